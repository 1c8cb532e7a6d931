"""rig register on the simulated rig: touch points (default run) and mocap RCM frames (slow)."""

from __future__ import annotations

import numpy as np
import pytest

from rig.runs.paths import latest_result
from tests.procedures._cli import run_cli


def test_register_touch_meets_targets_and_is_found_by_later_runs():
    code, r, err = run_cli("register", "--json", "--seed", "2")
    assert code == 0, err
    e = r["truth"]["PSM2"]
    assert e["rcm_translation_error"] < 0.5e-3 and e["rcm_rotation_error_deg"] < 0.2
    assert e["base_translation_error"] < 0.5e-3 and e["base_rotation_error_deg"] < 0.2
    found = latest_result("register")
    assert found is not None
    frames = {a: np.array(T) for a, T in found[1]["rcm_frames"].items()}
    assert set(frames) == {"PSM1", "PSM2"}
    # PSM2's RCM frame in the common frame is where the configured rig puts it
    from rig import config
    from rig.model import psm_kinematics as K
    cfg = config.load()
    true = cfg.base_matrix("PSM2") @ K.RCM_FRAME
    assert np.linalg.norm(frames["PSM2"][:3, 3] - true[:3, 3]) < 0.5e-3


def test_a_touch_puts_the_tool_tips_together_and_register_records_the_tool_tips():
    """A person brings the tool tips together (the jaws' tips), not the shaft ends 9.1 mm
    behind them: after the simulated person's touch each arm's tool tip, by the dVRK's own
    kinematics (PSMKinematics.forward: the tip on the wrist-yaw axis), is on the point, and
    what register records for it is that tool tip (issue 45, item 6)."""
    from drivers.operator.sim import SimOperator
    from rig import config
    from rig.model import psm_kinematics as K
    from rig.model.psm_arm_kinematics import PSMKinematics, tool_tip_in_rcm
    from rig.sim.world import world_from_config

    from procedures.register import touch_points

    cfg = config.load()
    world = world_from_config(cfg, ["PSM1", "PSM2"], seed=0)
    person = SimOperator(world, {})
    kin = PSMKinematics()
    for goal in touch_points(cfg, ["PSM1", "PSM2"], 4, 0.03):
        person.touch(["PSM1", "PSM2"], 0, goal)
        for arm in ("PSM1", "PSM2"):
            q = world.q[world.arms[arm].sl]
            rcm = world.arms[arm].rcm_world
            tool_tip = (rcm @ kin.forward(np.concatenate([q, np.zeros(3)])))[:3, 3]
            assert np.linalg.norm(tool_tip - goal) < 1e-9, (arm, tool_tip - goal)
            shaft_end = (rcm @ np.append(K.tip_in_rcm(q), 1.0))[:3]
            assert abs(np.linalg.norm(shaft_end - goal) - 0.0091) < 1e-9  # the shaft end is 9.1 mm short
            recorded = (rcm @ np.append(tool_tip_in_rcm(q), 1.0))[:3]
            assert np.linalg.norm(recorded - goal) < 1e-9


def test_the_tool_tip_follows_the_wrist():
    """A bent wrist moves the tool tip off the shaft line: a whole arm's wrist joints count."""
    from rig.model import psm_kinematics as K
    from rig.model.psm_arm_kinematics import tool_tip_in_rcm

    q = np.array([0.1, -0.2, 0.12])
    straight = tool_tip_in_rcm(q)
    bent = tool_tip_in_rcm(q, [0.0, 0.5, 0.0])
    assert abs(np.linalg.norm(straight - K.tip_in_rcm(q)) - 0.0091) < 1e-9
    assert abs(np.linalg.norm(bent - K.tip_in_rcm(q)) - 0.0091) < 1e-9  # the same wrist length, turned
    assert np.linalg.norm(bent - straight) > 0.004


@pytest.mark.slow
def test_register_mocap_meets_targets_on_the_rcm_frames():
    code, r, err = run_cli("register", "--method", "mocap", "--json", "--seed", "4")
    assert code == 0, err
    e = r["truth"]["PSM2"]
    assert e["rcm_translation_error"] < 0.5e-3 and e["rcm_rotation_error_deg"] < 0.2
    assert r["rcm_source"] == "measured in this run"


def test_register_mocap_uses_the_latest_rcm_calibration(monkeypatch):
    # a calibrate-rcm run of this rig with every arm's RCM frame is used without moving anything
    from rig import config
    from rig.runs import provenance
    from rig.model import psm_kinematics as K
    from rig.runs.run import Run

    cfg = config.load()
    arms = {a: {"rcm_frame": (cfg.base_matrix(a) @ K.RCM_FRAME).tolist()} for a in cfg.arms}
    with Run("calibrate-rcm", progress=False) as run:
        run.finish({"arms": arms, "provenance": provenance.live(cfg, list(cfg.arms), run.dir)})
    code, r, err = run_cli("register", "--method", "mocap", "--json")
    assert code == 0, err
    assert r["rcm_source"] == str(run.dir)
    assert r["truth"]["PSM2"]["rcm_translation_error"] < 1e-9

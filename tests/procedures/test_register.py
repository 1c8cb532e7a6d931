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

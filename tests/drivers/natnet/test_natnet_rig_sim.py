"""`rig sim --natnet` in one process, a procedure reading mocap through NatNet in another.

The lab's rig.toml of tests/hil (ROS arms, rig sim's operator) with `[mocap] driver =
"natnet"` on ports of its own: `rig calibrate-rcm` finds the RCM through the fake Motive
as it does through ROS mocap (tests/hil/test_chain.py), and with nobody serving NatNet it
stops with one line naming the address and what to do.
"""

from __future__ import annotations

import numpy as np
import pytest

import rclpy  # noqa: E402,F401  (a declared dependency: a broken install fails here)

from tests.hil.harness import ServedRig, completed, lab_toml  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.hil]


def natnet_toml(folder, port: int, extra: str = "") -> str:
    text = lab_toml(folder).replace('[mocap]\ndriver = "ros"\n',
                                    f'[mocap]\ndriver = "natnet"\ncommand_port = {port}\ndata_port = {port + 1}\n')
    assert 'driver = "natnet"' in text
    return text + extra


# 29 s: left out of the default run (under 10 min); the driver's loopback tests and
# test_no_natnet_server_is_one_line cover `rig sim --natnet` there. Run with -m slow.
@pytest.mark.slow
def test_calibrate_rcm_and_link_lengths_through_the_fake_motive(tmp_path, free_ports):
    from procedures.link_lengths import nominal_lengths
    from rig import config
    from rig.model import psm_kinematics as K

    port = free_ports(2)  # NatNet's command and data ports; the domain is claimed by ServedRig
    with ServedRig(tmp_path / "lab", toml=natnet_toml(tmp_path / "lab", port),
                   sim_args=("--no-loadcell",)) as rig:
        assert f"natnet: 127.0.0.1:{port} (data {port + 1}, unicast, NatNet 4.1, 120 Hz)" in rig.sim_lines
        out = rig.run("calibrate-rcm", "--arm", "PSM1", "--duration", "6", "--q1-range", "0.5", "--q2-range", "0.4")
        lengths = rig.run("link-lengths", "--q1-range", "0.5", "--q2-range", "0.4", "--passes", "1",
                          "--q3-stroke", "0.05")
    doc = completed(out, "calibrate-rcm")
    # the same bound as the chain's link-lengths through ROS mocap (tests/hil/test_chain.py)
    true = nominal_lengths()
    for key in ("l1", "l2", "l3", "l4"):
        value = completed(lengths, "link-lengths")["lengths"][key]["value"]
        assert abs(value - true[key]) < 0.003, (key, value, true[key])
    assert "mocap 6 bodies" in out.stderr  # connected to PSM1's five and the world body
    cfg = config.load(tmp_path / "lab" / "rig.toml")
    true = (cfg.base_matrix("PSM1") @ K.RCM_FRAME)[:3, 3]
    assert np.linalg.norm(np.array(doc["arms"]["PSM1"]["rcm"]) - true) < 0.002


def test_no_natnet_server_is_one_line(tmp_path, free_ports):
    port = free_ports(2)  # nobody serves them: claimed, so no other test's fake Motive is there
    toml = natnet_toml(tmp_path / "lab", port, "\n[ros]\nconnect_timeout = 3.0\n")
    with ServedRig(tmp_path / "lab", toml=toml, sim_args=("--no-loadcell", "--no-natnet")) as rig:
        out = rig.run("calibrate-rcm", "--arm", "PSM1")
    assert out.code == 3 and "Traceback" not in out.stderr
    assert out.last_line.startswith(f"rig calibrate-rcm: aborted: no NatNet server answered at 127.0.0.1:{port} "
                                    "within 3 s")
    assert "rig sim --natnet" in out.last_line

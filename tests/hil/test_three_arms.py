"""Three arms over the wire: `rig sim` serves PSM3 and a load cell per object element.

On simulated time in lockstep (`rig sim --sim-time`): the figures are the loop's, however
busy the machine.

The lab's rig.toml names a port per element (`[loadcell] ports`); rig sim links each to
the pty of that element's firmware, each cell is calibrated on its own (`--element`), and
the cooperative procedure opens the three, each with its own calibration.
"""

from __future__ import annotations

import pytest

import rclpy  # noqa: E402,F401  (a declared dependency: a broken install fails here)

from tests.hil.harness import ServedRig, completed, lab_toml  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.hil]


@pytest.fixture(scope="module")
def triangle(tmp_path_factory):
    folder = tmp_path_factory.mktemp("triangle")
    # the arms' servo at 500 Hz (a console's, whatever the procedures' [rig] rate): the
    # triangle's loop needs their streams at 500 Hz
    with ServedRig(folder, toml=lab_toml(folder, three_arms=True, sim_time=True), sim_time=True,
                   sim_args=("--rate", "500")) as rig:
        yield rig


@pytest.fixture(scope="module")
def calibrated(triangle):
    """Each element's cell calibrated on its own (`--element k`), once per module."""
    return [completed(triangle.run("loadcell-calibrate", "--seconds", "0.5", "--element", str(k)),
                      f"loadcell-calibrate --element {k}") for k in range(3)]


def test_each_element_has_its_cell_calibrated_on_its_own_port(triangle, calibrated):
    ports = [str(triangle.folder / n) for n in ("loadcell", "loadcell1", "loadcell2")]
    for k, (port, doc) in enumerate(zip(ports, calibrated)):
        assert doc["device"]["port"] == port
        # the simulated operator hung 0.5 kg on this element's cell (noise 20 mN rms)
        assert abs(doc["check"]["error_n"]) < 0.02, (k, doc["check"])
    out = triangle.run("loadcell-calibrate", "--seconds", "0.5")
    assert out.code != 0 and "Traceback" not in out.stderr
    assert "--element 0..2" in out.last_line, out.last_line


@pytest.mark.slow
def test_three_arms_hold_5_newtons_on_every_element(triangle, calibrated):
    completed(triangle.run("register", "--points", "6"), "register")
    for arm in ("PSM1", "PSM2", "PSM3"):  # each arm runs on its own model: every one identified
        completed(triangle.run("identify", "--arm", arm, "--duration", "10", "--starts", "1", "--iterations", "5",
                               "--no-plots"), f"identify {arm}")
    doc = completed(triangle.run("cooperative", "--arms", "PSM1,PSM2,PSM3", "--force", "5", "--object", "spring",
                           "--move", "0.03,0,0", "--duration", "2", "--settle", "1.5", "--hold-after", "0.5"),
              "cooperative (three arms)")
    assert doc["max_error_during_motion"] <= 0.25, doc["summary"]
    assert doc["overshoot"] <= 0.5, doc["summary"]
    from procedures.cooperative import ARM_LOOP_MAX_RATE

    # the slaves' impedance in the arms (servo_ci): the loop moves their goals at up to 100 Hz
    assert doc["loop_timing"]["rate_hz"] == ARM_LOOP_MAX_RATE

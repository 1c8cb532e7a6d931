"""Where the dVRK's CRTK messages cannot load, every command that needs them says so in one
line naming the Python and the fix, before it opens anything (issue 45, item 2)."""

import sys

import pytest
from click.testing import CliRunner

from drivers.common import crtk_messages
from rig.cli import main

ROS_ARMS = '[arms.PSM1]\ndriver = "ros"\n[arms.PSM2]\ndriver = "ros"\nbase_xyz = [1.0728, 0.0, 0.0]\n' \
           'base_rpy = [0.0, 0.0, 3.141592653589793]\n[loadcell]\ndriver = "none"\n[mocap]\ndriver = "none"\n'


@pytest.fixture
def no_crtk_msgs(monkeypatch):
    """This interpreter as one the package ships no message libraries for: the import fails."""
    for name in [m for m in sys.modules if m == "crtk_msgs" or m.startswith("crtk_msgs.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "crtk_msgs", None)  # `import crtk_msgs...` raises ImportError
    monkeypatch.setattr(crtk_messages, "_checked", False)
    monkeypatch.setattr(crtk_messages, "_problem", None)
    yield
    crtk_messages._checked = False


def test_problem_names_the_python_and_the_fix(no_crtk_msgs):
    why = crtk_messages.problem()
    version = f"{sys.version_info.major}.{sys.version_info.minor}"
    assert why is not None and f"Python {version}" in why and "pip install -e ." in why and "\n" not in why


@pytest.mark.parametrize("command", [["identify", "--yes"], ["cooperative", "--yes"], ["friction-ramp", "--yes"]])
def test_a_procedure_on_ros_arms_stops_in_one_line(no_crtk_msgs, tmp_path, command, monkeypatch):
    """Not the old way (the arms opened without their operating state, never enabled nor
    homed, the run failing later on 'cannot run servo_ci'): exit 5, one line."""
    toml = tmp_path / "rig.toml"
    toml.write_text(ROS_ARMS)
    if command[0] == "cooperative":  # past its models and registration: the simulated ones will do
        monkeypatch.setattr("procedures.cooperative._registration_for", lambda *a, **k: ({}, "test"))
        monkeypatch.setattr("procedures.cooperative._model_for", lambda *a, **k: {})
    res = CliRunner().invoke(main, ["--config", str(toml), *command])
    assert res.exit_code == 5, res.output
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "need the CRTK messages" in lines[0] and "Python" in lines[0], res.stderr


def test_rig_sim_stops_in_one_line(no_crtk_msgs):
    res = CliRunner().invoke(main, ["sim", "--duration", "0.1"])
    assert res.exit_code == 5, res.output
    assert "rig sim serves the dVRK's CRTK messages" in res.stderr and len(res.stderr.strip().splitlines()) == 1

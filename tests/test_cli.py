import json
import subprocess
import sys

from click.testing import CliRunner

from rig import __version__
from rig.cli import COMMANDS, main

DESIGN_COMMANDS = ["link-lengths", "calibrate-rcm", "register", "identify", "friction-ramp",
                   "cooperative", "discrepancy", "sim"]


def test_help_lists_the_design_commands():
    out = CliRunner().invoke(main, ["--help"]).output
    for name in DESIGN_COMMANDS:
        assert name in out
        assert name in COMMANDS


def test_version():
    out = CliRunner().invoke(main, ["--version"]).output
    assert __version__ in out


def test_console_script_runs_without_importing_heavy_modules():
    code = "import sys; from rig.cli import main; print('pinocchio' in sys.modules, 'rclpy' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["False", "False"]


def test_selftest_json(tmp_path):
    res = CliRunner().invoke(main, ["selftest", "--duration", "2.0", "--json"])
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout.strip().splitlines()[-1])
    assert data["status"] == "completed"
    for arm in ("PSM1", "PSM2"):
        assert data["arms"][arm]["settling_time"] < 2.0
        assert abs(data["arms"][arm]["final_error"][2]) < 5e-4


def test_selftest_reports_a_bad_config(tmp_path):
    (tmp_path / "bad.toml").write_text('[rig]\nrate = "fast"\n')
    res = CliRunner().invoke(main, ["--config", str(tmp_path / "bad.toml"), "selftest"])
    assert res.exit_code != 0
    assert "rig.rate: expected a number" in res.output

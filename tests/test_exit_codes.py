"""One exit status per kind of ending (rig.commands.exit_codes), as `rig --help` and the README say:
a user's configuration or input is not a bug."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from rig.commands.exit_codes import EXIT_ABORTED, EXIT_INPUT, EXIT_USAGE, MEANINGS

REPO = Path(__file__).resolve().parents[1]


def _rig(folder: Path, *args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, RIG_LOGS=str(folder / "logs"), PYTHONPATH=str(REPO))
    env.pop("RIG_DEBUG", None)
    return subprocess.run([sys.executable, "-m", "rig.cli", *args], cwd=folder, env=env, capture_output=True,
                          text=True, timeout=300)


def _one_line(out: subprocess.CompletedProcess) -> str:
    assert "Traceback" not in out.stderr, out.stderr
    lines = [ln for ln in out.stderr.splitlines() if ln.strip()]
    assert lines, out
    return lines[-1]


@pytest.mark.parametrize("toml, args, code, words", [
    ("", ("identify", "--no-such-option"), EXIT_USAGE, "No such option"),
    ("[rig]\nsede = 1\n", ("selftest",), EXIT_INPUT, "did you mean rig.seed?"),
    ("", ("friction-ramp", "--arm", "PSM9"), EXIT_INPUT, "no arm 'PSM9'"),
    ("", ("cooperative", "--force", "5", "--model", "/no/such/model.json"), EXIT_INPUT, "/no/such/model.json"),
    ('[loadcell]\ndriver = "serial"\nport = "{folder}/no-port"\n', ("loadcell-calibrate", "--seconds", "0.2", "--yes"),
     EXIT_ABORTED, "cannot open"),
])
def test_each_kind_of_ending_has_its_code(tmp_path, toml, args, code, words):
    if toml:
        (tmp_path / "rig.toml").write_text(toml.format(folder=tmp_path))
    out = _rig(tmp_path, *args)
    assert out.returncode == code, (out.returncode, out.stderr[-2000:])
    assert words in _one_line(out)


def test_a_malformed_csv_is_the_users_input(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("0.1,0.2,0.3,0.4,0.5,0.6,0.7,0.8,0.9\n0.1,0.2\n")
    out = _rig(tmp_path, "validate", "--csv", str(bad), "--model", str(bad))
    assert out.returncode == EXIT_INPUT, out.stderr[-2000:]
    assert str(bad) in _one_line(out)


def test_help_lists_every_code():
    out = _rig(REPO, "--help")
    assert out.returncode == 0
    for code, text in MEANINGS:
        assert f"{code:>3}  {text}" in out.stdout, out.stdout

"""Every file a user names on the command line, given wrong, is one line naming it.

Each command's file option (or argument) is given a missing path, a binary file, a text
file of the wrong kind (the README), a malformed CSV and a directory. Each must end
non-zero with one line on stderr that names the path, and no exception may escape to
click (which a user would see as a traceback).
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from click.testing import CliRunner

from rig.cli import main

REPO = Path(__file__).resolve().parents[1]
WPI = REPO.parent / "shared" / "data" / "wpi-psm" / "one_results.csv"

# name -> argv with {f} where the file goes
CASES = {
    "identify --csv": ["identify", "--csv", "{f}", "--no-plots"],
    "identify --validate-csv": ["identify", "--csv", str(WPI), "--validate-csv", "{f}", "--no-plots"],
    "discrepancy --csv": ["discrepancy", "--csv", "{f}"],
    "discrepancy RUN_DIR": ["discrepancy", "{f}"],
    "discrepancy --model": ["discrepancy", "--csv", str(WPI), "--model", "{f}"],
    "discrepancy --validate-csv": ["discrepancy", "--csv", str(WPI), "--validate-csv", "{f}"],
    "export RUN": ["export", "{f}", "--csv", "{tmp}/out.csv"],
    "calibrate-rcm --from-csv": ["calibrate-rcm", "--from-csv", "{f}", "--body", "tool"],
    "cooperative --model": ["cooperative", "--model", "{f}", "--duration", "1"],
    "sim --plant-model": ["sim", "--plant-model", "{f}", "--duration", "1"],
    "--config": ["--config", "{f}", "runs"],
    "loadcell-calibrate --port": ["loadcell-calibrate", "--port", "{f}", "--seconds", "0.2"],
    "validate --model": ["validate", "--model", "{f}", "--csv", str(WPI)],
    "validate --csv": ["validate", "--model", "{model}", "--csv", "{f}"],
    "validate RUN_DIR": ["validate", "--model", "{model}", "{f}"],
    "validate --compare": ["validate", "--model", "{model}", "--csv", str(WPI), "--compare", "{f}"],
}


@pytest.fixture(scope="module")
def bad_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("bad")
    (d / "binary.bin").write_bytes(bytes(range(256)) * 8)
    (d / "malformed.csv").write_text("a,b,c\n1,2\nx,y,z\n")
    (d / "README.md").write_text((REPO / "README.md").read_text())
    (d / "a-folder").mkdir()
    from rig.model.model_file import save_model
    from rig.model.psm_dynamics import PSMDynamics, standard_parameter_names

    save_model(d / "good" / "model.json", standard=PSMDynamics().standard_params(), names=standard_parameter_names(),
               slope=400.0, gravity=[0.0, 0.0, -9.81])
    return {"missing": d / "nope.csv", "binary": d / "binary.bin", "malformed": d / "malformed.csv",
            "wrong kind": d / "README.md", "directory": d / "a-folder"}


@pytest.mark.parametrize("kind", ["missing", "binary", "malformed", "wrong kind", "directory"])
@pytest.mark.parametrize("case", list(CASES))
def test_a_bad_file_is_one_line_naming_it(case, kind, bad_files, tmp_path, monkeypatch):
    if str(WPI) in CASES[case] and not WPI.exists():
        pytest.skip("the shared WPI recording is not here")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("RIG_LOGS", str(tmp_path / "logs"))
    monkeypatch.delenv("RIG_CONFIG", raising=False)
    path = bad_files[kind]
    model = path.parent / "good" / "model.json"
    argv = [a.replace("{f}", str(path)).replace("{tmp}", str(tmp_path)).replace("{model}", str(model))
            for a in CASES[case]]
    res = CliRunner().invoke(main, argv)
    assert res.exit_code != 0, res.output
    # an exception click did not turn into a message is a traceback for the user
    assert res.exception is None or isinstance(res.exception, SystemExit), repr(res.exception)
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert lines, res.output
    assert "Traceback" not in res.output
    assert os.path.basename(str(path)) in lines[-1], lines[-1]
    assert "a bug of rig" not in lines[-1], lines[-1]

"""Results handed from one procedure to the next are taken only where they belong
(rig.runs.provenance): the chains a lab runs, with a foreign model, a registration of another
rig configuration and a model file edited by hand."""

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from rig import config, sealed_json
from rig.cli import main
from rig.commands.exit_codes import EXIT_MISSED
from rig.runs import provenance

WPI = Path(__file__).resolve().parents[3] / "shared" / "data" / "wpi-psm" / "one_results.csv"
SHORT = ["--duration", "1", "--settle", "1.5", "--hold-after", "0.2"]


def _json(res) -> dict:
    return json.loads([x for x in res.stdout.splitlines() if x.startswith("{")][-1])


def _model_of(path, cfg, arms=("PSM1",), scale=1.0):
    from rig.model.model_file import save_model
    from rig.model.psm_dynamics import PSMDynamics, standard_parameter_names

    return save_model(path, standard=PSMDynamics().standard_params() * scale, names=standard_parameter_names(),
                      slope=400.0, gravity=np.array([0.0, 0.0, -9.81]),
                      provenance_info={"data_source": "test", **provenance.live(cfg, list(arms), path.parent)})


def _as_identify_run(model_path: Path, name="20261125T000000000000Z-identify") -> Path:
    """A completed identify run folder holding `model_path` (as `rig identify` leaves it)."""
    run = Path("logs") / name
    run.mkdir(parents=True)
    (run / "model.json").write_bytes(model_path.read_bytes())
    (run / "result.json").write_text(json.dumps({"status": "completed", "procedure": "identify",
                                                 "model": str((run / "model.json").resolve())}))
    return run


@pytest.mark.skipif(not WPI.exists(), reason="the shared WPI recording is not here")
def test_a_model_of_another_arm_is_skipped_refused_or_forced_and_the_untensioned_run_fails():
    """The issue's chain: `rig identify --csv` on a public recording of another PSM, then the
    string on the simulated rig. Implicitly the model is skipped (the run names it and why)
    and the string is held; given with --model it is refused in one line; forced, the run
    carries the warning and, never tensioned, ends 'failed' with exit 4."""
    ident = CliRunner().invoke(main, ["identify", "--csv", str(WPI), "--json"])
    assert ident.exit_code == 0, ident.output
    model = _json(ident)["model"]
    prov = json.loads(Path(model).read_text())["provenance"]
    assert prov["rig"] is None and prov["source"]["csv"] == str(WPI.resolve())
    assert len(prov["source"]["sha256"]) == 64 and prov["package_version"] and prov["digest"]

    res = CliRunner().invoke(main, ["cooperative", "--object", "string", "--move", "0,0.02,0", *SHORT, "--json"])
    assert res.exit_code == 0, res.output
    data = _json(res)
    assert data["status"] == "completed" and all(m["note"].startswith(f"{arm}: nominal model")
                                                 for arm, m in data["models"].items())
    assert data["warnings"] == [f"{arm}: set aside: skipped identify run {Path(model).parent.name}: it was "
                                f"computed from {WPI.resolve()}, not measured on this rig" for arm in ("PSM1", "PSM2")]
    assert data["max_error_during_motion"] < 0.5

    res = CliRunner().invoke(main, ["cooperative", "--object", "string", "--model", model, *SHORT])
    assert res.exit_code == 5 and "Traceback" not in res.output
    line = res.output.strip().splitlines()[-1]
    assert "not a model of any of PSM1, PSM2 on this rig" in line and "--force-model" in line
    assert "rig identify" in line

    res = CliRunner().invoke(main, ["cooperative", "--object", "string", "--move", "0,0.02,0", "--model", model,
                                    "--force-model", *SHORT, "--json"])
    assert res.exit_code == EXIT_MISSED, res.output
    data = _json(res)
    assert data["status"] == "failed" and "never settled" in data["error"]
    assert data["warnings"][0].startswith(f"--force-model: {model} used although it was computed from")
    assert res.stderr.strip().splitlines()[-1].startswith("rig cooperative: failed: the tension never settled")


def test_a_registration_of_another_rig_configuration_is_not_used(tmp_path):
    """`rig register` on one configuration; PSM2 then moved by 2 cm in rig.toml. The
    simulated rig falls back to the configured bases and says which run it skipped; a real
    rig stops with one line saying to register (before any device is opened)."""
    reg = CliRunner().invoke(main, ["register", "--json"])
    assert reg.exit_code == 0, reg.output
    reg_run = Path(_json(reg)["run_dir"]).name
    assert _json(reg)["provenance"]["arms"][1]["name"] == "PSM2"

    moved = tmp_path / "moved.toml"
    moved.write_text(f'[arms.PSM1]\n[arms.PSM2]\nbase_xyz = [{config.DEFAULT_PSM2_X + 0.02}, 0.0, 0.0]\n'
                     'base_rpy = [0.0, 0.0, 3.141592653589793]\n')
    res = CliRunner().invoke(main, ["--config", str(moved), "cooperative", "--dry-run", "--json"])
    assert res.exit_code == 0, res.output
    data = _json(res)
    assert data["registration"] == "the configuration's arm bases (simulated rig)"
    assert len(data["warnings"]) == 1
    # what moved, old and new (issue 45, item 7)
    assert data["warnings"][0] == (f"skipped register run {reg_run}: PSM2 was measured on another placement "
                                   f"(base_xyz [{config.DEFAULT_PSM2_X}, 0.0, 0.0] then, "
                                   f"[{round(config.DEFAULT_PSM2_X + 0.02, 6)}, 0.0, 0.0] now): a base moved in "
                                   "rig.toml moves the arm's results with it; run the procedure again")
    # the same configuration still takes it
    res = CliRunner().invoke(main, ["cooperative", "--dry-run", "--json"])
    assert _json(res)["registration"].endswith(reg_run) and not _json(res)["warnings"]

    ros = tmp_path / "ros.toml"
    ros.write_text('[arms.PSM1]\ndriver = "ros"\n[arms.PSM2]\ndriver = "ros"\n'
                   f'base_xyz = [{config.DEFAULT_PSM2_X}, 0.0, 0.0]\nbase_rpy = [0.0, 0.0, 3.141592653589793]\n')
    model = _model_of(tmp_path / "m" / "model.json", config.load(ros), arms=("PSM1", "PSM2"))
    res = CliRunner().invoke(main, ["--config", str(ros), "cooperative", "--model", str(model)])
    assert res.exit_code == 5 and "Traceback" not in res.output
    line = res.output.strip().splitlines()[-1]
    assert "run `rig register` first" in line and f"skipped register run {reg_run}" in line


def test_a_model_file_edited_by_hand_is_passed_over_until_forced(tmp_path):
    """A model of this rig, whose provenance is then edited (here: the source run renamed).
    Implicitly it is skipped with the reason; with --model it is refused; --force-model uses
    it and says so. Unedited, the same file is taken implicitly."""
    cfg = config.load()
    model = _model_of(tmp_path / "m" / "model.json", cfg, scale=1.05)
    run = _as_identify_run(model)
    res = CliRunner().invoke(main, ["cooperative", "--dry-run", "--json"])
    assert _json(res)["models"]["PSM1"]["file"] == str((run / "model.json").resolve())

    doc = json.loads((run / "model.json").read_text())
    doc["provenance"]["source"]["run"] = "20261101T000000000000Z-identify"
    (run / "model.json").write_text(json.dumps(doc))
    res = CliRunner().invoke(main, ["cooperative", "--dry-run", "--json"])
    data = _json(res)
    assert data["models"]["PSM1"]["note"].startswith("PSM1: nominal model")
    # PSM1's model set aside, named once; PSM2 never had one of its own, and is told nothing of PSM1's
    assert data["warnings"] == [f"PSM1: set aside: skipped identify run {run.name}: it was edited after it was "
                                "written (its digest does not match)"]
    res = CliRunner().invoke(main, ["cooperative", "--dry-run", "--model", str(run / "model.json")])
    assert res.exit_code == 5 and "edited after it was written" in res.output and "Traceback" not in res.output
    res = CliRunner().invoke(main, ["cooperative", "--dry-run", "--json", "--force-model", "--model",
                                    str(run / "model.json")])
    assert res.exit_code == 0, res.output
    assert "edited after it was written" in _json(res)["warnings"][0]


def test_a_model_of_another_simulated_plant_is_foreign():
    """The arm's identity follows its plant: a model measured on PSM1 with a hidden
    joint-3 stiction is not a model of the nominal PSM1, nor the reverse."""
    nominal = config.load()
    sticky = config.parse({"arms": {"PSM1": {}, "PSM2": {"base_xyz": [config.DEFAULT_PSM2_X, 0, 0],
                                                                  "base_rpy": [0, 0, 3.141592653589793]}},
                                   "effects": {"PSM1": {"stiction": [0.0, 0.0, 1.0]}}}, "sticky.toml")
    doc = {"provenance": provenance.live(sticky, ["PSM1"], "run")}
    sealed_json.seal(doc)
    assert provenance.mismatch(doc, sticky) is None
    why = provenance.mismatch(doc, nominal)
    assert why is not None and why.startswith("its PSM1 is simulated PSM1 (plant ")
    assert provenance.arm_identity(sticky, "PSM1") != provenance.arm_identity(nominal, "PSM1")
    assert provenance.arm_identity(sticky, "PSM2") == provenance.arm_identity(nominal, "PSM2")


def test_a_model_of_psm1_still_belongs_when_psm3_joins_but_not_when_psm1_is_moved():
    """Belonging is per arm: adding an arm to the configuration changes the rig's hash but
    not PSM1's mounting; moving PSM1's base (or changing gravity) does."""
    two = config.load()
    doc = sealed_json.seal({"provenance": provenance.live(two, ["PSM1"], "run")})
    pi = 3.141592653589793
    three = config.parse({"arms": {"PSM1": {}, "PSM2": {"base_xyz": [config.DEFAULT_PSM2_X, 0, 0],
                                                        "base_rpy": [0, 0, pi]},
                                   "PSM3": {"base_xyz": [0.5, 0.9, 0], "base_rpy": [0, 0, -pi / 2]}}}, "three.toml")
    assert provenance.rig_identity(three) != provenance.rig_identity(two)
    assert provenance.mismatch(doc, three) is None
    tilted = config.parse({"arms": {"PSM1": {"base_rpy": [0.1, 0, 0]}}}, "tilted.toml")
    # the line says what moved (issue 45, item 7), not only that a hash differs
    assert provenance.mismatch(doc, tilted).startswith("PSM1 was measured on another placement (base_rpy "
                                                       "[0.0, 0.0, 0.0] then, [0.1, 0.0, 0.0] now)")
    # a result written before the placement was recorded in the clear still says the hashes
    old = {"provenance": {**doc["provenance"], "arms": [{k: v for k, v in a.items() if k in ("name", "identity",
                                                                                           "mounting")}
                                                       for a in doc["provenance"]["arms"]]}}
    assert provenance.mismatch(sealed_json.seal(old), tilted).startswith(
        "it was measured on another rig configuration (PSM1's mounting or gravity differ")


def test_adding_a_serial_sets_earlier_results_aside_and_says_so_in_one_line():
    """Results keyed on the arm's identity: a serial added to rig.toml later names itself as
    the reason, and several runs set aside are one line."""
    plain = config.parse({"arms": {"PSM1": {"driver": "ros"}}}, "plain.toml")
    serial = config.parse({"arms": {"PSM1": {"driver": "ros", "serial": "28914"}}}, "serial.toml")
    doc = sealed_json.seal({"provenance": provenance.live(plain, ["PSM1"], "run")})
    why = provenance.mismatch(doc, serial)
    assert "[arms.PSM1] serial was added after it was measured" in why, why
    line = provenance.set_aside_line([f"skipped identify run B: {why}", f"skipped identify run A: {why}"])
    assert line.startswith("2 results set aside, the newest: skipped identify run B: ") and "\n" not in line

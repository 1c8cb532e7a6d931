"""rig cooperative runs each arm on its own identified model and friction terms, never
another arm's (issue 45, item 1); an arm with none is refused on a real rig in one line."""

import json
import os

import numpy as np
from click.testing import CliRunner

from rig import config
from rig.cli import main
from rig.model.model_file import StickSlip, save_model
from rig.model.psm_dynamics import PSMDynamics, standard_parameter_names
from rig.runs import provenance
from rig.runs.paths import run_dir_name, runs_root
from rig.sealed_json import seal_provenance, write_result

REAL_RIG = """
[arms.PSM1]
driver = "ros"
[arms.PSM2]
driver = "ros"
base_xyz = [1.0728, 0.0, 0.0]
base_rpy = [0.0, 0.0, 3.141592653589793]
[loadcell]
driver = "none"
[mocap]
driver = "none"
"""


def _identified(cfg, arm: str, scale: float, stamp: str) -> str:
    """A completed identify run of `arm` on rig `cfg` in logs/ (its model's parameters the
    nominal ones times `scale`); the model file's path."""
    run = runs_root() / f"{stamp}-identify"
    run.mkdir(parents=True)
    path = save_model(run / "model.json", standard=PSMDynamics().standard_params() * scale,
                      names=standard_parameter_names(), slope=400.0, gravity=np.array([0.0, 0.0, -9.81]),
                      provenance_info={"data_source": f"test: {arm} nominal x {scale}",
                                       **provenance.live(cfg, [arm], run)})
    write_result(run / "result.json", {"status": "completed", "model": str(path)})
    return str(path)


def _ramp(cfg, arm: str, fs: float, stamp: str) -> str:
    """A completed friction-ramp run of `arm` with breakaways +-fs N; its folder."""
    run = runs_root() / f"{stamp}-friction-ramp"
    run.mkdir(parents=True)
    stick = StickSlip(3, fs, -fs, provenance={"run_dir": str(run)})
    result = {"status": "completed", "arm": arm, "stick_slip": stick.to_dict(),
              "provenance": provenance.live(cfg, [arm], run)}
    seal_provenance(result)
    write_result(run / "result.json", result)
    return str(run)


def _json(res):
    return json.loads([x for x in res.stdout.splitlines() if x.startswith("{")][-1])


def test_a_model_identified_on_psm2_is_never_used_for_psm1():
    """The guide's order: identify PSM1, then PSM2. PSM2's model is the newest, and PSM1
    still runs on its own (the dry run's result names each arm's file)."""
    cfg = config.load()
    own = _identified(cfg, "PSM1", 1.05, "20260101T000000000000Z")
    other = _identified(cfg, "PSM2", 1.1, "20260101T010000000000Z")
    res = CliRunner().invoke(main, ["cooperative", "--dry-run", "--json"])
    assert res.exit_code == 0, res.output
    data = _json(res)
    assert data["models"]["PSM1"]["file"] == own
    assert data["models"]["PSM2"]["file"] == other


def test_an_arm_without_a_model_of_its_own_runs_nominal_on_the_simulated_rig():
    cfg = config.load()
    other = _identified(cfg, "PSM2", 1.1, "20260101T010000000000Z")
    res = CliRunner().invoke(main, ["cooperative", "--dry-run", "--json"])
    assert res.exit_code == 0, res.output
    models = _json(res)["models"]
    assert models["PSM1"]["file"] is None and "nominal model" in models["PSM1"]["note"]
    assert models["PSM2"]["file"] == other


def test_a_real_rig_refuses_an_arm_with_no_model_naming_the_command(tmp_path):
    """Only PSM2 identified: the run stops before any device opens, in one line naming
    `rig identify --arm PSM1` (exit 5, input)."""
    toml = tmp_path / "rig.toml"
    toml.write_text(REAL_RIG)
    cfg = config.load(str(toml))
    _identified(cfg, "PSM2", 1.1, "20260101T010000000000Z")
    res = CliRunner().invoke(main, ["--config", str(toml), "cooperative", "--dry-run"])
    assert res.exit_code == 5, res.output
    last = res.stderr.strip().splitlines()[-1]
    assert "no identified model of PSM1 on this rig" in last and "`rig identify --arm PSM1`" in last, last
    assert len(res.stderr.strip().splitlines()) == 1


def test_each_arm_takes_only_its_own_friction_ramp():
    """A friction ramp of PSM2 merges into PSM2's model only; PSM1 keeps its own terms."""
    cfg = config.load()
    _identified(cfg, "PSM1", 1.05, "20260101T000000000000Z")
    _identified(cfg, "PSM2", 1.1, "20260101T010000000000Z")
    ramp1 = _ramp(cfg, "PSM1", 0.7, "20260101T020000000000Z")
    ramp2 = _ramp(cfg, "PSM2", 1.3, "20260101T030000000000Z")
    from procedures.cooperative import _model_for

    models = _model_for(cfg, ["PSM1", "PSM2"], (), simulated=True)
    assert models["PSM1"].stick.fs_pos == 0.7 and models["PSM2"].stick.fs_pos == 1.3
    assert models["PSM1"].stick_file == os.path.join(ramp1, "stick_slip.json")
    assert models["PSM2"].stick_file == os.path.join(ramp2, "stick_slip.json")
    # and the controller's feedforward is each arm's: the parameters differ by their scale
    p1 = models["PSM1"].dynamics.standard_params()
    p2 = models["PSM2"].dynamics.standard_params()
    nominal = PSMDynamics().standard_params()
    big = np.argmax(np.abs(nominal))
    assert np.isclose(p1[big] / nominal[big], 1.05) and np.isclose(p2[big] / nominal[big], 1.1)


def test_model_option_goes_to_the_arm_its_file_names_and_refuses_another_arms(tmp_path):
    cfg = config.load()
    psm2 = _identified(cfg, "PSM2", 1.1, "20260101T010000000000Z")
    res = CliRunner().invoke(main, ["cooperative", "--dry-run", "--json", "--model", psm2])
    assert res.exit_code == 0, res.output
    models = _json(res)["models"]
    assert models["PSM2"]["file"] == psm2 and models["PSM1"]["file"] is None
    res = CliRunner().invoke(main, ["cooperative", "--dry-run", "--model", f"PSM1={psm2}"])
    assert res.exit_code == 5, res.output
    assert "not a model of PSM1 on this rig" in res.stderr and "rig identify --arm PSM1" in res.stderr


def test_a_slave_whose_console_does_not_subscribe_servo_ci_is_refused_in_one_line():
    """The check is the console's subscription (RosArm.servo_ci_problem, from the ROS graph),
    not whether the Python type imports: an arm that can build the message but whose
    console does not listen is refused, naming --slave-control effort."""
    import pytest

    from procedures.cooperative import _pace_at_published_rate
    from rig.runs.run import AbortRun

    class Arm:
        supports_servo_ci = True  # the type imports here

        def __init__(self, problem):
            self.problem = problem

        def servo_ci_problem(self):
            return self.problem

        def published_rate(self):
            return 500.0

    class Rig:
        arms = {"PSM1": Arm("/PSM1/servo_ci: the console does not subscribe to it"), "PSM2": Arm(None)}

    with pytest.raises(AbortRun) as err:
        _pace_at_published_rate(Rig(), ["PSM1", "PSM2"], "PSM2")
    text = str(err.value.reason)
    assert "PSM1 cannot run its impedance in the arm: /PSM1/servo_ci: the console does not subscribe" in text
    assert "--slave-control effort" in text and "\n" not in text

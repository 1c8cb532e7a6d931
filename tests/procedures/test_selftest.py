"""`rig selftest`: a verdict per check with its bound, exit 4 when one fails, and why the
object is already loaded when the lift starts."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from rig.cli import main
from rig.commands.exit_codes import EXIT_MISSED


def selftest(*args, config=None):
    pre = ["--config", str(config)] if config else []
    res = CliRunner().invoke(main, pre + ["selftest", *args, "--json"])
    assert "Traceback" not in res.output
    doc = json.loads(res.stdout.strip().splitlines()[-1]) if res.stdout.strip() else None
    return res, doc


def checks(doc):
    return {c["name"]: c for c in doc["checks"]}


def test_the_built_in_rig_passes_every_check_and_explains_its_tension():
    res, doc = selftest()
    assert res.exit_code == 0, res.output
    assert doc["status"] == "completed"
    by_name = checks(doc)
    assert sorted(by_name) == ["PSM1 settled", "PSM1-PSM2 tension change", "PSM2 settled", "rate"]
    for c in doc["checks"]:
        assert c["passed"] and c["bound"] is not None and c["bound_text"], c
    for arm in ("PSM1", "PSM2"):
        c = by_name[f"{arm} settled"]
        assert 0 < c["value"] <= c["bound"] < doc["simulated_time"]
        assert c["bound"] == pytest.approx(doc["simulated_time"] - doc["arms"][arm]["loop_period"])
    t = doc["tension"]["PSM1-PSM2"]
    assert t["change"] == pytest.approx(t["final"] - t["before_lift"])
    assert abs(t["change"]) <= t["bound"] == by_name["PSM1-PSM2 tension change"]["bound"]
    # The reading before the lift is the spring's law at the measured tip distance (plus a
    # small damper share while the arms still move) ...
    spring = t["stiffness"] * (t["distance_before_lift"] - t["rest_length"])
    assert t["before_lift"] == pytest.approx(spring, abs=0.01 * abs(spring))
    # ... and the built-in rig starts relaxed: the compression comes from the sag.
    assert t["distance_at_q0"] == pytest.approx(t["rest_length"], abs=1e-9)
    assert t["before_lift"] < 0 and t["distance_before_lift"] < t["distance_at_q0"]

    report = res.stderr
    assert "selftest: passed all 4 checks" in report
    for line in ("PSM1 settled", "PSM2 settled", "PSM1-PSM2 tension change", "rate"):
        row = next(r for r in report.splitlines() if r.strip().startswith(line))
        assert " pass " in row and ("<=" in row or "within" in row or ">=" in row), row
    assert "why the object reads what it reads" in report
    assert "the arms sag" in report and "the sag moved them" in report and "closer" in report


def test_the_sag_before_the_lift_follows_the_joint_loads(tmp_path):
    """The physics behind the explanation: each joint sags against its steady load (gravity
    plus the drives' friction offset Fo), by less than the P term alone would allow; without
    gravity only Fo is left, and the object is loaded far less before the lift."""
    from rig.model.psm_dynamics import DriveParameters
    from rig.sim.world import PIDGains

    drive, pid = DriveParameters(), PIDGains()
    _, doc = selftest()
    for arm in ("PSM1", "PSM2"):
        load = np.array(doc["arms"][arm]["load_at_q0"])
        sag = np.array(doc["arms"][arm]["sag_before_lift"])
        moving = np.abs(load) > drive.Fc  # below its Coulomb level friction can hold a joint
        assert moving.any()
        assert np.all(np.sign(sag[moving]) == -np.sign(load[moving]))
        assert np.all(np.abs(sag) <= np.abs(load) / pid.kp)

    (tmp_path / "space.toml").write_text("[rig]\ngravity = [0.0, 0.0, 0.0]\n")
    res, weightless = selftest(config=tmp_path / "space.toml")
    assert res.exit_code == 0, res.output
    for arm in ("PSM1", "PSM2"):
        np.testing.assert_allclose(weightless["arms"][arm]["load_at_q0"], drive.Fo, atol=1e-12)
    loaded = doc["tension"]["PSM1-PSM2"]["before_lift"]
    assert abs(weightless["tension"]["PSM1-PSM2"]["before_lift"]) < 0.5 * abs(loaded)


def test_too_short_a_run_fails_with_exit_4_and_names_the_checks():
    res, doc = selftest("--duration", "0.2")
    assert res.exit_code == EXIT_MISSED == 4
    assert doc["status"] == "failed"
    by_name = checks(doc)
    assert not by_name["PSM1 settled"]["passed"] and not by_name["PSM2 settled"]["passed"]
    assert by_name["rate"]["passed"]
    last = res.stderr.strip().splitlines()[-1]
    assert last.startswith("rig selftest: failed: PSM1 settled: final error outside")
    assert "FAILED" in res.stderr and "PSM1 settled" in res.stderr.splitlines()[-2]
    row = next(r for r in res.stderr.splitlines() if r.strip().startswith("PSM1 settled"))
    assert " FAIL " in row and "<= " in row  # the bound is printed with the verdict


def test_an_arm_that_cannot_hold_its_load_fails(tmp_path):
    # 1.5 kg on PSM2's tool: more than its insertion drive can hold against gravity
    (tmp_path / "heavy.toml").write_text("[effects.PSM2]\npayload_mass = 1.5\n")
    res, doc = selftest(config=tmp_path / "heavy.toml")
    assert res.exit_code == EXIT_MISSED, res.output
    by_name = checks(doc)
    assert not by_name["PSM2 settled"]["passed"]
    assert "PSM2 settled" in res.stderr.strip().splitlines()[-1]
    # the report says why: the insertion's integral term is clamped below the load it carries
    assert 3 in doc["arms"]["PSM2"]["integral_at_limit"]
    from rig.sim.world import PIDGains

    assert f"PSM2 q3: limit {PIDGains().integral_limit[2]:g} N" in res.stderr


def test_bad_configurations_are_one_line(tmp_path):
    # an insertion so shallow that the lift would take the tip above the RCM
    (tmp_path / "shallow.toml").write_text("[arms.PSM1]\nq0 = [0.0, 0.0, 0.005]\n")
    res = CliRunner().invoke(main, ["--config", str(tmp_path / "shallow.toml"), "selftest"])
    assert res.exit_code == 5
    assert len(res.output.strip().splitlines()) == 1, res.output
    assert "PSM1 cannot lift its tip 10 mm" in res.output and "Traceback" not in res.output
    (tmp_path / "ros.toml").write_text('[arms.PSM1]\ndriver = "ros"\n[arms.PSM2]\ndriver = "ros"\n')
    res = CliRunner().invoke(main, ["--config", str(tmp_path / "ros.toml"), "selftest"])
    assert res.exit_code == 5 and len(res.output.strip().splitlines()) == 1, res.output
    assert "no simulated arm to test" in res.output
    res = CliRunner().invoke(main, ["selftest", "--duration", "0.0001"])
    assert res.exit_code == 5 and len(res.output.strip().splitlines()) == 1
    assert "less than one step of the rig" in res.output

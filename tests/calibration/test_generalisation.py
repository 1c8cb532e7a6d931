"""Effects are written only where they predict other motion (calibration.generalisation,
issue 26), and a given model is taken whole (calibration.prediction.extra_effort)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from calibration.discrepancy.settings import Settings
from calibration.generalisation import NOT_CONFIRMED, EffectGate, Motion
from calibration.plain_model import plain_fit, plain_training_block
from calibration.hidden_effects import HiddenCase, draw_case_parameters
from calibration.prediction import predict
from tests.sim_cache import recorded


def _plain_model(rec, tmp_path, name="plain.json"):
    from rig.model.model_file import load_model, save_model

    out = plain_fit(plain_training_block(rec.q, rec.dq, rec.tau, rec.rate, Settings().heldout))
    sdp = out.fits["sdp"]
    return load_model(save_model(tmp_path / name, standard=sdp.pi, names=list(out.model.param_names()),
                                 slope=out.slope, gravity=out.gravity, stribeck=out.stribeck()))


def _named(effect: str, joint: int, grid, params=None, k: int = 1):
    return SimpleNamespace(effect=effect, joint=joint, grid=grid, free=np.ones(k, bool), params=params or {})


@pytest.fixture(scope="module")
def hysteresis_case(tmp_path_factory):
    """Joint 3 with a Dahl hysteresis the plain model lacks: three trajectories of the same
    plant (training, the other motion, the test)."""
    case = HiddenCase((("hysteresis", 3),), 0)
    train, _ = recorded(case)
    other, _ = recorded(case, trajectory_seed=500)
    test, _ = recorded(case, trajectory_seed=900)
    plain = _plain_model(train, tmp_path_factory.mktemp("hyst"))
    p = draw_case_parameters(case)[0]
    travel = p["size"] / p["stiffness"]
    return SimpleNamespace(train=train, other=other, test=test, plain=plain, travel=travel)


def test_a_true_effect_is_confirmed_and_predicts_an_unseen_motion_better(hysteresis_case):
    c = hysteresis_case
    named = [_named("hysteresis", 3, c.travel), _named("spring", 1, None, k=2)]
    gate = EffectGate(c.plain, named, c.train.q, c.train.dq, c.train.tau, c.train.rate, Settings(),
                      motions=[Motion(c.other.q, c.other.dq, c.other.tau, c.other.rate, "other")])
    r = gate.run()
    assert r.doc["kept"] == ["hysteresis@3"]
    dropped = {(d["effect"], d["joint"]): d for d in r.doc["not_confirmed"] + r.doc["implausible"]}
    assert ("spring", 1) in dropped
    # on a third trajectory neither fit saw
    plain = predict(c.plain, c.test.q, c.test.dq, c.test.tau, c.test.rate).figures("all")["relative_error"]
    written = predict(gate.model_file(r.kept, r.refit_joints), c.test.q, c.test.dq, c.test.tau, c.test.rate).figures("all")
    assert written["relative_error"][2] < 0.8 * plain[2]
    # nothing kept on joint 1 but, perhaps, its friction refitted where that confirmed
    assert written["relative_error"][0] <= plain[0] * 1.005
    # the Dahl level is the plant's within 25 %
    fd = next(e for e in r.entries if e["name"] == "hysteresis")["params"]["Fd"]
    truth = draw_case_parameters(HiddenCase((("hysteresis", 3),), 0))[0]["size"]
    assert fd == pytest.approx(truth, rel=0.25)


def test_with_one_motion_cross_validation_in_time_keeps_the_true_effect_only(hysteresis_case):
    c = hysteresis_case
    named = [_named("hysteresis", 3, c.travel), _named("hysteresis", 1, 0.01)]
    r = EffectGate(c.plain, named, c.train.q, c.train.dq, c.train.tau, c.train.rate, Settings()).run()
    assert "cross-validation" in r.doc["method"]
    assert r.doc["kept"] == ["hysteresis@3"]
    assert {(d["effect"], d["joint"]) for d in r.doc["not_confirmed"] + r.doc["implausible"]} == {("hysteresis", 1)}


def test_nothing_confirmed_writes_the_plain_model(tmp_path):
    """A null plant: effects named on it are not confirmed on the other motion, and the
    written model is the plain one, parameter for parameter."""
    train, _ = recorded(HiddenCase((), 7))
    other, _ = recorded(HiddenCase((), 7), trajectory_seed=507)
    plain = _plain_model(train, tmp_path)
    named = [_named("hysteresis", 2, 0.004), _named("spring", 3, None, k=2)]
    gate = EffectGate(plain, named, train.q, train.dq, train.tau, train.rate, Settings(),
                      motions=[Motion(other.q, other.dq, other.tau, other.rate, "other")])
    r = gate.run()
    assert r.kept == [] and r.entries == []
    # the rigid body is the plain model's; so is the friction of every joint not refitted
    np.testing.assert_array_equal(r.standard[:70], plain.standard[:70])
    for j in {1, 2, 3} - set(r.refit_joints):
        np.testing.assert_array_equal(r.standard[66 + 4 * j:70 + 4 * j], plain.standard[66 + 4 * j:70 + 4 * j])
    written, plain_err = r.doc["relative_error"]["written"], r.doc["relative_error"]["plain"]
    assert all(w <= p for w, p in zip(written, plain_err))
    assert all(w == p for j, (w, p) in enumerate(zip(written, plain_err), 1) if j not in r.refit_joints)
    reasons = [d["why"] for d in r.doc["not_confirmed"]] + [d["why"] for d in r.doc["implausible"]]
    assert len(reasons) == 2 and any(NOT_CONFIRMED in why for why in reasons)


def test_a_given_model_is_taken_whole(tmp_path):
    """`rig discrepancy --model M`: the baseline is M's whole effort. A torque offset entry
    in M moves the fixed effort of joint 2 by exactly that offset on every raw sample."""
    from calibration.base_params import base_parameters_of
    from calibration.discrepancy.workflow import Discrepancy
    from calibration.prediction import extra_effort, standard_parameters
    from rig.model.psm_kinematics import DQ_MAX, Q_MAX, Q_MIN

    rec, _ = recorded(HiddenCase((), 3))
    plain = _plain_model(rec, tmp_path)
    doc = dict(plain.document, effects=[{"name": "torque_offset", "joint": 2, "params": {"offset": 0.25}}])
    from dataclasses import replace

    with_offset = replace(plain, document=doc)
    dyn = with_offset.dynamics()
    base = base_parameters_of(dyn.regressor_batch, dyn, Q_MIN, Q_MAX, DQ_MAX)
    pi = standard_parameters(with_offset)
    bare = Discrepancy(dyn, base, rec.q, rec.dq, rec.tau, rec.rate, pi, Settings())
    whole = Discrepancy(dyn, base, rec.q, rec.dq, rec.tau, rec.rate, pi, Settings(),
                        given_extra=lambda p: extra_effort(with_offset, p))
    diff = (whole.fixed_raw - bare.fixed_raw).reshape(-1, 3)
    stribeck = with_offset.stribeck
    if stribeck is None or not np.any(stribeck["Fst"]):
        np.testing.assert_allclose(diff[:, 0], 0.0, atol=1e-12)
    np.testing.assert_allclose(diff[:, 1], 0.25, atol=1e-12)


def test_the_workflows_own_model_is_written_only_if_the_other_motion_prefers_it(hysteresis_case):
    """`refit` (the workflow's model, its rigid body fitted again) competes on the other
    motion: a model that predicts it worse than the plain one on a joint is passed over."""
    from dataclasses import replace

    c = hysteresis_case
    worse = replace(c.plain, document=dict(c.plain.document, effects=[
        {"name": "torque_offset", "joint": 1, "params": {"offset": 0.2}},
        {"name": "hysteresis", "joint": 3, "params": {"Fd": 0.6, "travel": c.travel, "sigma0": 0.6 / c.travel}}]))
    motion = Motion(c.other.q, c.other.dq, c.other.tau, c.other.rate, "other")
    gate = EffectGate(c.plain, [_named("hysteresis", 3, c.travel)], c.train.q, c.train.dq, c.train.tau,
                      c.train.rate, Settings(), motions=[motion], refit=worse)
    r = gate.run()
    assert r.doc["choice"] == "plain model + confirmed effects" and r.model is None
    assert r.doc["refitted_rigid_body_relative_error"][0] > r.doc["relative_error"]["plain"][0]
    assert r.doc["kept"] == ["hysteresis@3"]


def test_with_another_motion_the_plain_model_is_identified_again_with_a_confirmed_effect(tmp_path):
    """A spring on the insertion joint tilts the plain model's gravity (every joint is
    biased, not only joint 3); identified again with the spring's column the model predicts
    a third trajectory at the plant's level, and it is written because the other motion
    prefers it. On a null plant the same candidate is never written."""
    from calibration.generalisation import IDENTIFIED_CHOICE

    case = HiddenCase((("spring", 3),), 1)
    train, _ = recorded(case)
    other, _ = recorded(case, trajectory_seed=501)
    test, _ = recorded(case, trajectory_seed=901)
    block = plain_training_block(train.q, train.dq, train.tau, train.rate, Settings().heldout)
    plain = _plain_model(train, tmp_path)
    spring = SimpleNamespace(effect="spring", joint=3, grid=None, free=np.array([True, False]), params={})
    gate = EffectGate(plain, [spring], train.q, train.dq, train.tau, train.rate, Settings(),
                      motions=[Motion(other.q, other.dq, other.tau, other.rate, "other")], training=block)
    r = gate.run()
    assert r.doc["choice"] == IDENTIFIED_CHOICE and r.doc["kept"] == ["spring@3"]
    written = gate.written_model(r)
    tilt = np.degrees(np.arccos(-written.gravity[2] / np.linalg.norm(written.gravity)))
    assert tilt < 1.0
    assert written.effects[0]["params"]["k"] == pytest.approx(draw_case_parameters(case)[0]["size"], rel=0.03)
    p = predict(plain, test.q, test.dq, test.tau, test.rate).figures("all")["relative_error"]
    w = predict(written, test.q, test.dq, test.tau, test.rate).figures("all")["relative_error"]
    assert all(a < b for a, b in zip(w, p))
    assert w[2] < 0.2 * p[2]
    # the plain model + spring on top is kept in the result, passed over
    assert r.doc["plain_with_confirmed_effects"]["kept"] == ["spring@3"]


def test_on_a_null_plant_the_identified_candidate_is_not_written(tmp_path):
    from calibration.generalisation import IDENTIFIED_CHOICE

    train, _ = recorded(HiddenCase((), 8))
    other, _ = recorded(HiddenCase((), 8), trajectory_seed=508)
    block = plain_training_block(train.q, train.dq, train.tau, train.rate, Settings().heldout)
    plain = _plain_model(train, tmp_path)
    named = [_named("hysteresis", 2, 0.004), _named("spring", 1, None, k=2)]
    named[1].free = np.array([True, False])
    r = EffectGate(plain, named, train.q, train.dq, train.tau, train.rate, Settings(),
                   motions=[Motion(other.q, other.dq, other.tau, other.rate, "other")], training=block).run()
    assert r.doc["choice"] != IDENTIFIED_CHOICE and r.model is None
    assert r.doc["identified_with_effects"] is not None   # it was tried
    np.testing.assert_array_equal(r.standard[:70], plain.standard[:70])


def test_an_offset_confirmed_as_its_joints_refitted_Fo_is_written_as_that_term(hysteresis_case):
    """A torque offset (or a spring's constant part -k q0) not confirmed as an entry but as
    its joint's friction refitted alone is written as that joint's Fo, when the refit moved
    Fo by the named size within a factor of 2; otherwise it stays not confirmed."""
    c = hysteresis_case
    offset = _named("torque_offset", 3, None, {"offset": 0.4})
    spring = _named("spring", 2, None, {"k": 0.5, "q0": -0.6}, k=2)
    gate = EffectGate(c.plain, [offset, spring], c.train.q, c.train.dq, c.train.tau, c.train.rate, Settings())
    gate.all[0].params, gate.all[1].params = {"offset": 0.4}, {"k": 0.5, "q0": -0.6}
    not_confirmed = [{"effect": "torque_offset", "joint": 3, "why": NOT_CONFIRMED},
                     {"effect": "spring", "joint": 2, "why": NOT_CONFIRMED}]
    standard = gate.pi.copy()
    standard[70 + 4 * 2 + 2] += 0.36     # joint 3's Fo moved by 0.36 N (0.4 named)
    standard[70 + 4 * 1 + 2] += 0.25     # joint 2's Fo moved by 0.25 N m (the spring's constant: 0.3)
    folded = gate._folded({2, 3}, not_confirmed, standard)
    assert [(f["effect"], f["joint"]) for f in folded] == [("torque_offset", 3), ("torque_offset", 2)]
    assert folded[0]["written"] == pytest.approx(0.36) and folded[1]["named"] == pytest.approx(0.3)
    assert "spring@2" in folded[1]["from"]
    # not refitted, or moved the other way, or 3 times the named size: not written
    assert gate._folded({2}, not_confirmed[:1], standard) == []
    standard[70 + 4 * 2 + 2] = gate.pi[70 + 4 * 2 + 2] - 0.36
    assert gate._folded({3}, not_confirmed[:1], standard) == []
    standard[70 + 4 * 2 + 2] = gate.pi[70 + 4 * 2 + 2] + 1.2
    assert gate._folded({3}, not_confirmed[:1], standard) == []

"""Catalogue effects identified with the rigid body (calibration.identification
fit_identification(effects=...), issue 26): an effect the model lacks biases the whole fit,
the gravity direction first; with its columns in the regressor the fit recovers the plant."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.discrepancy.settings import Settings
from calibration.plain_model import plain_training_block
from calibration.hidden_effects import HiddenCase, draw_case_parameters
from calibration.identification import DEADBAND, EffectTerm, fit_identification
from tests.sim_cache import recorded

#: The simulated rig's gravity (rig.model.psm_dynamics default, PSM frame 0).
DOWN = np.array([0.0, 0.0, -1.0])


def _tilt_deg(g) -> float:
    return float(np.degrees(np.arccos(np.clip(np.asarray(g) @ DOWN / np.linalg.norm(g), -1.0, 1.0))))


@pytest.fixture(scope="module")
def spring3():
    case = HiddenCase((("spring", 3),), 1)
    rec, _ = recorded(case)
    train = plain_training_block(rec.q, rec.dq, rec.tau, rec.rate, Settings().heldout)
    return train, draw_case_parameters(case)[0]


def test_an_unmodelled_spring_tilts_the_gravity_and_its_columns_restore_it(spring3):
    train, truth = spring3
    plain = fit_identification(train, "auto", "auto", deadband=DEADBAND)
    # the spring's constant is the joint's offset Fo: only its stiffness column is fitted
    term = EffectTerm("spring", 3, None, (True, False))
    with_spring = fit_identification(train, "auto", "auto", deadband=DEADBAND, effects=[term])
    assert _tilt_deg(plain.gravity) > 10.0
    assert _tilt_deg(with_spring.gravity) < 1.0
    (entry,) = with_spring.effect_entries("test")
    assert entry["name"] == "spring" and entry["joint"] == 3
    assert entry["params"]["k"] == pytest.approx(truth["size"], rel=0.03)
    # the columns are in the fit's extra rows, after the Stribeck column
    assert with_spring.fits["sdp"].extra.size == 2
    assert with_spring.extra_rows(train).shape == (3 * train.n_samples, 2)


def test_identifiable_effects_are_those_of_the_motion_alone():
    assert EffectTerm.identifiable("spring") and EffectTerm.identifiable("hysteresis")
    assert EffectTerm.identifiable("position_friction") and EffectTerm.identifiable("stiction")
    # a lag or a play is built from the model's torque; an offset or a payload is the rigid body's own term
    for effect in ("time_delay", "backlash", "torque_offset", "payload", "coulomb_asymmetry"):
        assert not EffectTerm.identifiable(effect)
    # with a fixed model's torque a delay's column can be built; a play needs the mass matrix too
    assert EffectTerm.identifiable("time_delay", with_model_torque=True)
    assert not EffectTerm.identifiable("backlash", with_model_torque=True)
    with pytest.raises(ValueError, match="time_delay@3: its columns need a model's torque"):
        EffectTerm("time_delay", 3, 0.02, (True,)).columns(np.zeros((10, 3)), np.zeros((10, 3)), np.zeros((10, 3)),
                                                           200.0, 400.0)


def test_inseparable_columns_are_refused_by_name(spring3):
    """The spring's constant beside the offset Fo: the fit names the dependent pair."""
    from calibration.base_params import RankDeficientError

    train, _ = spring3
    with pytest.raises(RankDeficientError, match="joint3.spring.c0"):
        fit_identification(train, "auto", 400.0, deadband=DEADBAND,
                           effects=[EffectTerm("spring", 3, None, (True, True))])


def test_an_effect_the_joints_friction_reproduces_is_found_inseparable(spring3):
    """A Dahl hysteresis of 0.2 mm travel on the insertion joint is, in the identification's
    3.5 Hz band, a Coulomb step: its column is reproduced by joint 3's friction columns
    (R^2 0.98 on this motion). A spring's stiffness column is not, nor a joint-1 Dahl
    state of 2 mrad travel."""
    from calibration.identification import SEPARABLE_R2, inseparable_effects

    rec, _ = recorded(HiddenCase((("hysteresis", 3),), 1))
    train = plain_training_block(rec.q, rec.dq, rec.tau, rec.rate, Settings().heldout)
    dahl = EffectTerm("hysteresis", 3, 0.0002, (True,))
    others = [EffectTerm("spring", 3, None, (True, False)), EffectTerm("hysteresis", 1, 0.002, (True,))]
    found = inseparable_effects(train, [dahl] + others)
    assert [t for t, _ in found] == [dahl]
    assert found[0][1] >= SEPARABLE_R2

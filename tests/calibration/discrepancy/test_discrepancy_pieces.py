"""The discrepancy workflow on a record of several continuous recordings put end to end
(`rig identify`: the excitation, then the validation trajectory): nothing is computed
across a join."""

import numpy as np
import pytest

from calibration.discrepancy.candidates import _effect_columns
from calibration.discrepancy.detection import _last_reversal_position
from calibration.discrepancy.preparation import pieces_of, prepare
from calibration.discrepancy.settings import DiscrepancyError, Settings
from calibration.effects import CATALOGUE, EffectContext
from calibration.signals import settling_samples

RATE = 200.0


def _motion(n: int, seed: int, offset: float):
    """q, dq, tau (n, 3): a few sines per joint about ``offset``, moving at both ends."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / RATE
    f = rng.uniform(0.2, 0.7, size=(3, 3))
    ph = rng.uniform(0, 2 * np.pi, size=(3, 3))
    q = offset + 0.2 * np.sin(2 * np.pi * f[None] * t[:, None, None] + ph[None]).sum(-1)
    dq = 0.2 * (2 * np.pi * f[None] * np.cos(2 * np.pi * f[None] * t[:, None, None] + ph[None])).sum(-1)
    tau = 2.0 * q + 0.3 * np.tanh(200 * dq) + 0.01 * rng.normal(size=q.shape)
    return q, dq, tau


def test_each_piece_is_prepared_as_if_it_were_alone():
    """Filtered state, its derivative, the masked effort and the moving mask of a joined
    record are, sample for sample, those of each recording prepared on its own: the jump at
    the join (0.8 rad here, an unrecorded move) reaches neither filter nor derivative."""
    a, b = _motion(2400, 0, 0.0), _motion(1800, 1, 0.8)
    joined = [np.vstack([x, y]) for x, y in zip(a, b)]
    s = Settings()
    p = prepare(*joined, RATE, s, breaks=[2400])
    alone = [prepare(*a, RATE, s), prepare(*b, RATE, s)]
    trim = settling_samples(RATE, s.cutoff, s.order)
    assert p.pieces == [(0, 2400), (2400, 4200)]
    assert len(p.qf) == 4200 - 4 * trim
    assert p.kept_starts() == [2400 - 2 * trim]
    cut = 2400 - 2 * trim
    for name in ("qf", "dqf", "ddqf", "tauf"):
        got = getattr(p, name)
        np.testing.assert_allclose(got[:cut], getattr(alone[0], name), atol=1e-12, err_msg=name)
        np.testing.assert_allclose(got[cut:], getattr(alone[1], name), atol=1e-12, err_msg=name)
    np.testing.assert_array_equal(p.moving_raw, np.vstack([alone[0].moving_raw, alone[1].moving_raw]))
    # the effort-lagged state restarts too (its first sample holds, as a record's first does)
    np.testing.assert_allclose(p.q[2400:], alone[1].q, atol=1e-12)
    # held-out at the end of the kept samples, a guard of one settling length before it
    m = len(p.qf)
    assert p.heldout.stop == m and p.heldout.stop - p.heldout.start == round(0.25 * m)
    assert p.heldout.start - p.train.stop == trim


def test_one_piece_is_the_record_as_before():
    q, dq, tau = _motion(3000, 2, 0.1)
    p, p0 = prepare(q, dq, tau, RATE, Settings(), breaks=()), prepare(q, dq, tau, RATE, Settings())
    trim = settling_samples(RATE, 10.0, 4)
    assert p.kept == slice(trim, 3000 - trim) and p.pieces == [] and p.kept_starts() == []
    np.testing.assert_array_equal(p.tauf, p0.tauf)


def test_effect_states_start_afresh_with_each_recording():
    """A Dahl state, a play's side and a delay's history carried over a join would tie the
    second recording's first samples to how the first one ended."""
    a, b = _motion(1500, 3, 0.0), _motion(1500, 4, 0.5)
    q, dq = np.vstack([a[0], b[0]]), np.vstack([a[1], b[1]])
    tau_model = np.vstack([a[2], b[2]])
    pieces = pieces_of(3000, [1500])
    for eff_id, g in (("hysteresis", 0.01), ("time_delay", 0.04), ("stiction", 0.01)):
        eff = CATALOGUE[eff_id]
        ctx = EffectContext(q, dq, RATE, 400.0, tau_model)
        joined = _effect_columns(eff, ctx, 1, g, pieces)
        second = eff.columns(EffectContext(b[0], b[1], RATE, 400.0, b[2]), 1, g)
        np.testing.assert_allclose(joined[1500:], second, atol=1e-12, err_msg=eff_id)
        # run across the join, the memory effects differ there
        if eff_id != "stiction":
            assert not np.allclose(eff.columns(ctx, 1, g)[1500:1510], second[:10]), eff_id


def test_a_new_recording_begins_as_a_reversal():
    q = np.array([0.0, 1.0, 2.0, 3.0, 10.0, 11.0, 12.0])
    dq = np.ones(7)
    assert _last_reversal_position(q, dq).tolist() == [0.0] * 7
    assert _last_reversal_position(q, dq, [4]).tolist() == [0.0] * 4 + [10.0] * 3


def test_pieces_must_lie_inside_and_be_long_enough():
    q, dq, tau = _motion(3000, 5, 0.0)
    with pytest.raises(DiscrepancyError, match="inside the 3000 samples"):
        prepare(q, dq, tau, RATE, Settings(), breaks=[3000])
    with pytest.raises(DiscrepancyError, match=r"piece 2 of the record \(samples 2950-2999"):
        prepare(q, dq, tau, RATE, Settings(), breaks=[2950])


"""Fourier excitation: rest at both ends, limits at every sample, condition number reduced."""


import numpy as np
import pytest

from calibration.excitation import ExcitationDesigner, FourierTrajectory, rest_basis


def random_traj(seed, f=0.13, T=30.0):
    rng = np.random.default_rng(seed)
    Z = rest_basis(f, T)
    c = rng.normal(size=(3, Z.shape[1])) @ Z.T
    return FourierTrajectory(f, c[:, :5], c[:, 5:], rng.normal(size=3), T)


@pytest.mark.parametrize("T", [30.0, 1 / 0.13 * 4])  # not, and exactly, a whole number of periods
def test_rest_at_both_ends(T):
    Z = rest_basis(0.13, T)
    assert Z.shape[1] >= 5
    for seed in range(5):
        tr = random_traj(seed, T=T)
        q, dq, ddq = tr.sample([0.0, T])
        np.testing.assert_allclose(q[0], q[1], atol=1e-12)
        np.testing.assert_allclose(dq, 0, atol=1e-12)
        np.testing.assert_allclose(ddq, 0, atol=1e-12)


def test_derivatives_consistent_and_eq_5_28():
    tr = random_traj(1)
    t = np.linspace(0, 30, 30001)
    q, dq, ddq = tr.sample(t)
    dt = t[1] - t[0]
    np.testing.assert_allclose(np.gradient(q, dt, axis=0)[1:-1], dq[1:-1], atol=1e-5 * np.abs(dq).max())
    np.testing.assert_allclose(np.gradient(dq, dt, axis=0)[1:-1], ddq[1:-1], atol=1e-5 * np.abs(ddq).max())
    # Eq. 5.28 literally, joint 2, with w = 2 pi f.
    w = 2 * np.pi * 0.13
    l = np.arange(1, 6)
    ts = 7.3
    ref = np.sum(tr.a[1] / (w * l) * np.sin(w * l * ts) - tr.b[1] / (w * l) * np.cos(w * l * ts)) + tr.q0[1]
    assert tr.sample(ts)[0][0, 1] == pytest.approx(ref, abs=1e-12)
    assert FourierTrajectory.from_dict(tr.to_dict()).sample(ts)[0] == pytest.approx(tr.sample(ts)[0])


def test_short_optimisation_improves_and_respects_limits(arm, base):
    d = ExcitationDesigner(arm.regressor_batch, base.independent, arm.q_min, arm.q_max, arm.dq_max,
                           ddq_max=np.array([6.0, 6.0, 1.5]), duration=30.0, n_objective=150, n_constraint=600)
    # (its speed, < 4 s, is a benchmark figure: bench/bench_identification.py)
    # A budget of 0 s is spent once the first start is done: the second of three never begins.
    r = d.optimise(n_starts=3, seed=1, maxiter=8, time_budget=0.0)
    assert len(r.starts) == 1
    s = r.starts[0]
    assert r.condition_objective < s["seed_condition"]
    # Every full-rate sample within limits, at rest at both ends.
    q, dq, ddq = r.trajectory.sample(r.trajectory.times(200.0))
    assert q.shape == (6001, 3)
    assert np.all(q >= arm.q_min - 1e-12) and np.all(q <= arm.q_max + 1e-12)
    assert np.all(np.abs(dq) <= arm.dq_max + 1e-12) and np.all(np.abs(ddq) <= np.array([6.0, 6.0, 1.5]) + 1e-12)
    assert max(max(v) for v in r.limit_use.values()) <= 1.0 + 1e-9
    np.testing.assert_allclose(dq[[0, -1]], 0, atol=1e-12)
    np.testing.assert_allclose(q[0], q[-1], atol=1e-12)
    assert r.condition_full == pytest.approx(d.condition(r.trajectory, d.t_full))


def test_limits_enforced_when_optimiser_overshoots(arm, base):
    d = ExcitationDesigner(arm.regressor_batch, base.independent, arm.q_min, arm.q_max, arm.dq_max,
                           n_objective=100, n_constraint=200)
    huge = random_traj(3)
    huge = FourierTrajectory(0.13, huge.a * 50, huge.b * 50, 0.5 * (arm.q_min + arm.q_max), 30.0)
    fitted, scale = d._fit_full(huge)
    assert scale < 1
    use = d.limit_use(fitted)
    assert max(max(v) for v in use.values()) <= 1.0 + 1e-9


@pytest.mark.slow
def test_full_optimisation_reaches_the_condition_target(arm, base):
    # Every start runs (no time budget), so the result does not depend on the machine's
    # speed; the time the default 100 s budget allows, < 120 s, is a benchmark figure:
    # bench/bench_identification.py.
    d = ExcitationDesigner(arm.regressor_batch, base.independent, arm.q_min, arm.q_max, arm.dq_max)
    r = d.optimise(n_starts=4, seed=0, time_budget=np.inf)
    assert len(r.starts) == 4
    assert r.condition_full < 300.0

"""The object's stretch carries the tension where the torques cannot tell it (issue 47):
calibration.stretch_filter against a known elastic element and a torque estimate made the
way the momentum observer makes it (a first-order lag of the true tension, plus a bias
while the joints stick)."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.momentum_observer import DEFAULT_GAIN
from calibration.stretch_filter import StretchFilter

DT = 0.001


def _lag(values: np.ndarray) -> np.ndarray:
    """The observer's view: a first-order lag of rate DEFAULT_GAIN."""
    out, y, a = np.empty_like(values), 0.0, 1.0 - np.exp(-DEFAULT_GAIN * DT)
    for i, v in enumerate(values):
        y += a * (v - y)
        out[i] = y
    return out


def _run(f: StretchFilter, L, z, spread) -> np.ndarray:
    return np.array([f.update([L[i]], [z[i]], [spread[i]], DT)[0] for i in range(len(L))])


def test_a_creeping_tip_moves_the_estimate_while_stuck_joints_hide_it_from_the_torques():
    k, rest = 2450.0, 0.10
    n = 6000
    L = np.full(n, rest + 5.0 / k)
    L[3000:] -= np.linspace(0.0, 0.5 / k, n - 3000)      # the slave creeps in: -0.5 N over 3 s
    truth = k * (L - rest)
    z = _lag(truth)
    spread = np.full(n, 0.03)
    # after 3 s every joint sticks: the torques stay where the friction holds them (5.0 N)
    z[3000:] = z[2999]
    spread[3000:] = 0.5
    est = _run(StretchFilter(1, k), L, z, spread)
    assert abs(truth[-1] - 4.5) < 1e-9
    assert abs(est[-1] - truth[-1]) < 0.1, (est[-1], truth[-1])   # the torques alone: 0.5 N off
    assert abs(z[-1] - truth[-1]) > 0.45


def test_a_stiff_string_going_taut_is_followed_through_the_observers_lag():
    k, rest = 20000.0, 0.10
    t = np.arange(0.0, 2.0, DT)
    # slack, then taken up at 2 mm/s to a 6 N stretch, held
    L = np.minimum(rest - 1e-3 + 2e-3 * t, rest + 6.0 / k)
    truth = k * np.maximum(L - rest, 0.0)
    z = _lag(truth) + np.random.default_rng(1).normal(0.0, 0.02, len(t))
    est = _run(StretchFilter(1, k, pulls_only=True), L, z, np.full(len(t), 0.05))
    taut = np.argmax(truth > 0.0)
    after = slice(taut + 100, None)      # from 0.1 s after it went taut
    assert np.max(np.abs(est[after] - truth[after])) < 0.3
    assert np.max(np.abs(z[after] - truth[after])) > 1.0     # the observer's lag alone
    assert np.all(est[:taut] == 0.0)                          # slack: no tension


def test_a_stiffness_configured_twice_too_high_is_learned_where_the_torques_see_the_stretch():
    k_true, rest = 2450.0, 0.10
    t = np.arange(0.0, 40.0, DT)
    L = rest + (5.0 + 1.0 * np.sin(2 * np.pi * 0.5 * t)) / k_true
    truth = k_true * (L - rest)
    z = _lag(truth)
    f = StretchFilter(1, 2.0 * k_true)
    est = _run(f, L, z, np.full(len(t), 0.03))
    assert abs(f.k[0] / k_true - 1.0) < 0.05, f.k[0]
    last = t > 35.0
    # closer than the torques themselves, which lag a 0.5 Hz swing by 0.16 N
    assert np.max(np.abs(est[last] - truth[last])) < 0.5 * np.max(np.abs(z[last] - truth[last]))


@pytest.mark.parametrize("bad", [0.0, -10.0, float("nan")])
def test_a_stiffness_that_is_not_positive_is_refused(bad):
    with pytest.raises(ValueError, match="stiffness"):
        StretchFilter(1, bad)

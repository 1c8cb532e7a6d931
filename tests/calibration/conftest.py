"""Shared fixtures for the identification tests: a known-truth arm and exciting trajectories."""

import numpy as np
import pytest

from calibration.base_params import base_parameters_of
from calibration.excitation import FourierTrajectory, rest_basis
from calibration.reference_arm import ReferenceArm


def exciting_trajectory(arm, seed=0, duration=30.0, rate=200.0, fill=0.8, frequency_hz=0.13):
    """A random (not optimised) 5-harmonic trajectory at rest at both ends, within limits.

    Returns (t, q, dq, ddq). Random coefficients excite every base parameter of the arm,
    with a condition number in the thousands (an optimised one is near 100).
    """
    rng = np.random.default_rng(seed)
    Z = rest_basis(frequency_hz, duration)
    c = rng.normal(size=(3, Z.shape[1])) @ Z.T
    traj = FourierTrajectory(frequency_hz, c[:, :5], c[:, 5:], np.zeros(3), duration)
    t = traj.times(rate)
    q, dq, _ = traj.sample(t)
    mid, half = 0.5 * (arm.q_min + arm.q_max), 0.5 * (arm.q_max - arm.q_min)
    s = np.minimum(fill * half / np.abs(q - q.mean(0)).max(0), fill * arm.dq_max / np.abs(dq).max(0))
    traj = FourierTrajectory(frequency_hz, c[:, :5] * s[:, None], c[:, 5:] * s[:, None],
                             mid - s * q.mean(0), duration)
    return (t, *traj.sample(t))


@pytest.fixture(scope="session")
def make_trajectory():
    """The trajectory helper (tests import nothing by module name under --import-mode=importlib)."""
    return exciting_trajectory


@pytest.fixture(scope="session")
def arm():
    return ReferenceArm(seed=0)


@pytest.fixture(scope="session")
def base(arm):
    return base_parameters_of(arm.regressor_batch, arm.param_layout, arm.q_min, arm.q_max, arm.dq_max)


@pytest.fixture(scope="session")
def trajectory(arm):
    """(t, q, dq, ddq, W): 2001 samples at 100 Hz over 20 s and the standard regressor."""
    t, q, dq, ddq = exciting_trajectory(arm, seed=1, duration=20.0, rate=100.0)
    return t, q, dq, ddq, arm.regressor_batch(q, dq, ddq)

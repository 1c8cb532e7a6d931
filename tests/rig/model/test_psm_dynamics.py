import numpy as np
import pinocchio as pin
import pytest

from rig.model import psm_kinematics as K
from rig.model.psm_dynamics import COUPLING, PSMDynamics, PSMParameters, standard_parameter_names


@pytest.fixture(scope="module")
def dyn():
    return PSMDynamics()


def _samples(n, seed=0):
    rng = np.random.default_rng(seed)
    q = rng.uniform(K.Q_MIN, K.Q_MAX, (n, 3))
    dq = rng.uniform(-K.DQ_MAX, K.DQ_MAX, (n, 3))
    ddq = rng.normal(0, 3, (n, 3))
    return q, dq, ddq


def test_regressor_equals_projected_rnea_and_m_c_g(dyn):
    pi = dyn.standard_params()
    for q, dq, ddq in zip(*_samples(50)):
        tau_y = dyn.regressor(q, dq, ddq) @ pi
        tree = pin.rnea(dyn.model, dyn.data, COUPLING @ q, COUPLING @ dq, COUPLING @ ddq)
        tau_rnea = COUPLING.T @ tree + dyn.Ia * ddq + dyn.friction(dq)
        tau_mcg = (dyn.mass_matrix(q) @ ddq + dyn.coriolis(q, dq) + dyn.gravity_torque(q) + dyn.friction(dq))
        assert np.allclose(tau_y, tau_rnea, atol=1e-12)
        assert np.allclose(tau_y, tau_mcg, atol=1e-12)


def test_projection_obeys_the_power_balance(dyn):
    # Independent of the projection algebra: for the frictionless, unforced arm
    # d/dt (kinetic + potential) = dq . tau along a finely integrated motion.
    q, dq = np.array([0.2, -0.3, 0.12]), np.array([0.5, 0.4, 0.05])
    h = 1e-5
    for _ in range(100):
        tau = np.array([0.3, -0.2, 1.0])
        ddq = dyn.forward_dynamics(q, dq, tau, friction=False)
        e0 = dyn.energy(q, dq)
        q1, dq1 = q + h * dq + 0.5 * h * h * ddq, dq + h * ddq
        power = (dyn.energy(q1, dq1) - e0) / h
        assert power == pytest.approx(dq @ tau, rel=2e-3, abs=2e-4)
        q, dq = q1, dq1


def test_mass_matrix_symmetric_positive_definite_over_workspace(dyn):
    for q in _samples(500, 1)[0]:
        M = dyn.mass_matrix(q)
        assert np.allclose(M, M.T, atol=1e-14)
        assert np.linalg.eigvalsh(M).min() > 1e-3


def test_mdot_minus_2c_is_skew(dyn):
    q, dq = np.array([0.1, 0.5, 0.2]), np.array([0.7, -0.3, 0.1])
    eps = 1e-7
    Mdot = (dyn.mass_matrix(q + eps * dq) - dyn.mass_matrix(q - eps * dq)) / (2 * eps)
    S = Mdot - 2 * dyn.coriolis_matrix(q, dq)
    assert np.allclose(S, -S.T, atol=1e-6)
    assert np.allclose(dyn.coriolis_matrix(q, dq) @ dq, dyn.coriolis(q, dq), atol=1e-12)


def test_tip_from_pinocchio_tree_matches_dh_frames(dyn):
    for q in _samples(20, 2)[0]:
        assert np.allclose(dyn.tip_placement(q), K.frames(q)["tip"], atol=1e-12)
        assert np.allclose(dyn.tip_jacobian(q), K.geometric_jacobian(q), atol=1e-12)


def test_standard_parameters_round_trip_and_names(dyn):
    pi = dyn.standard_params()
    names = standard_parameter_names()
    assert len(pi) == len(names) == 82
    again = PSMParameters.from_standard_vector(pi).standard_vector()
    assert np.allclose(pi, again, atol=1e-12)
    assert pi[names.index("joint3.Fv")] == pytest.approx(0.7663)


def test_friction_is_eq_4_16_with_a_sigmoid(dyn):
    big = dyn.friction(np.array([1.0, 1.0, 1.0]))
    assert np.allclose(big, dyn.Fc + dyn.Fv + dyn.Fo, atol=1e-9)
    assert np.allclose(dyn.friction(np.zeros(3)), dyn.Fo)
    assert np.allclose(dyn.friction(-np.ones(3)), -dyn.Fc - dyn.Fv + dyn.Fo, atol=1e-9)


def test_nominal_torques_are_of_the_order_of_real_psm_data(dyn):
    # shared/data/wpi-psm efforts reach about 1.6 N m, 1.7 N m and 2.9 N on joints 1-3.
    q, dq, ddq = _samples(400, 3)
    ddq = ddq / 3
    tau = np.array([dyn.inverse_dynamics(a, b, c) for a, b, c in zip(q, dq, ddq)])
    peak = np.abs(tau).max(axis=0)
    assert np.all(peak > [0.5, 0.5, 1.0]) and np.all(peak < [6.0, 6.0, 12.0])

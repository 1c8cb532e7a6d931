"""The known-truth arm the fits are tested on must itself be right."""

import numpy as np

from calibration.estimators import check_physical, mass_matrix_from_regressor


def test_regressor_matches_rnea(arm):
    rng = np.random.default_rng(0)
    pi = arm.true_params()
    for _ in range(20):
        q, dq, ddq = rng.uniform(-1, 1, (3, 3))
        tau_y = arm.regressor(q, dq, ddq) @ pi
        tau_r = arm.torque_rnea(q, dq, ddq, pi)
        np.testing.assert_allclose(tau_y, tau_r, rtol=0, atol=1e-12 * (1 + np.abs(tau_r).max()))


def test_batch_is_sample_major(arm):
    rng = np.random.default_rng(1)
    Q, DQ, DDQ = rng.uniform(-1, 1, (3, 5, 3))
    W = arm.regressor_batch(Q, DQ, DDQ)
    for k in range(5):
        np.testing.assert_array_equal(W[3 * k:3 * k + 3], arm.regressor(Q[k], DQ[k], DDQ[k]))


def test_generic_mass_matrix_matches_crba(arm):
    rng = np.random.default_rng(2)
    pi = arm.true_params()
    for q in rng.uniform(arm.q_min, arm.q_max, (10, 3)):
        np.testing.assert_allclose(mass_matrix_from_regressor(arm.regressor, q, pi),
                                   arm.mass_matrix(q, pi), atol=1e-12)


def test_true_and_nominal_parameters_are_physical(arm):
    for pi in (arm.true_params(), arm.nominal_params()):
        assert check_physical(pi, arm.param_layout)["all_pass"]

"""Base parameters: exact regrouping W_b K = W, null space, inverse map, names, speed."""


import numpy as np
import pinocchio as pin
import pytest

from calibration.base_params import (RankDeficientError, base_parameters_of, compute_base_parameters,
                                     random_samples)
from calibration.layout import ParamLayout


def fresh_regressor(arm, seed):
    Q, DQ, DDQ = random_samples(60, arm.q_min, arm.q_max, arm.dq_max, seed=seed)
    return arm.regressor_batch(Q, DQ, DDQ)


def test_regrouping_is_exact_for_random_pi(arm, base):
    # On samples the base parameters were not computed from.
    W = fresh_regressor(arm, seed=123)
    Wb = base.regressor(W)
    rng = np.random.default_rng(0)
    for _ in range(10):
        pi = rng.normal(size=base.n_standard)
        lhs, rhs = Wb @ base.base_from_standard(pi), W @ pi
        assert np.abs(lhs - rhs).max() <= 1e-10 * np.abs(rhs).max()


def test_on_trajectory_too(base, trajectory):
    *_, W = trajectory
    pi = np.random.default_rng(1).normal(size=base.n_standard)
    rhs = W @ pi
    assert np.abs(base.regressor(W) @ (base.K @ pi) - rhs).max() <= 1e-10 * np.abs(rhs).max()


def test_rank_and_null_space(arm, base):
    W = fresh_regressor(arm, seed=7)
    assert np.linalg.matrix_rank(W) == base.n_base
    N = base.null_basis
    assert N.shape == (base.n_standard, base.n_standard - base.n_base)
    np.testing.assert_allclose(N.T @ N, np.eye(N.shape[1]), atol=1e-12)
    assert np.abs(W @ N).max() <= 1e-10 * np.abs(W).max()
    assert np.abs(base.K @ N).max() <= 1e-10


def test_inverse_map_round_trip(base, arm):
    rng = np.random.default_rng(2)
    beta = rng.normal(size=base.n_base)
    for free in (None, arm.nominal_params(), rng.normal(size=len(base.dependent))):
        pi = base.standard_from_base(beta, free)
        np.testing.assert_allclose(base.K @ pi, beta, atol=1e-12)
    # With the nominal as free part, the dependent parameters are the nominal ones.
    pi = base.standard_from_base(beta, arm.nominal_params())
    np.testing.assert_array_equal(pi[base.dependent], arm.nominal_params()[base.dependent])


def test_expressions_name_standard_parameters(base):
    ex = base.expressions()
    assert len(ex) == base.n_base
    # The tool is rigidly fixed to the insertion stage: only its sum with link3 is seen.
    assert "link3.m + tool.m" in ex
    # Every drive parameter but joint 1 and 2's rotor inertia (lumped with link Izz/Iyy) is its own base parameter.
    for name in ("joint1.Fc", "joint1.Fv", "joint1.Fo", "joint3.Fc", "joint3.Ia"):
        assert name in ex
    assert any("joint1.Ia" in e and "link1.Izz" in e for e in ex)
    # Tiny coefficients are dropped, none of the printed ones is numerical dust.
    for e in ex:
        assert "e-1" not in e


def test_sample_manipulator_regressor():
    """Generic: Pinocchio's own sample manipulator (6 revolute joints, no drive terms)."""
    model = pin.buildSampleModelManipulator()
    data = model.createData()
    rng = np.random.default_rng(3)
    rows = [pin.computeJointTorqueRegressor(model, data, *rng.uniform(-2, 2, (3, model.nv)))
            for _ in range(60)]
    W = np.vstack(rows)
    layout = ParamLayout(model.njoints - 1, 0)
    bp = compute_base_parameters(W, layout=layout)
    assert bp.n_base == np.linalg.matrix_rank(W)
    pi = np.concatenate([model.inertias[i].toDynamicParameters() for i in range(1, model.njoints)])
    Wt = np.vstack([pin.computeJointTorqueRegressor(model, data, *rng.uniform(-2, 2, (3, model.nv)))
                    for _ in range(10)])
    assert np.abs(bp.regressor(Wt) @ (bp.K @ pi) - Wt @ pi).max() <= 1e-10 * np.abs(Wt @ pi).max()
    assert "body1.m" in bp.names


def test_about_100_parameters_reduce(arm):
    # (its speed is a benchmark figure: bench/bench_identification.py)
    bp = base_parameters_of(arm.regressor_batch, arm.param_layout, arm.q_min, arm.q_max, arm.dq_max)
    assert arm.param_layout.n_params == 92 and bp.n_base < 92


def test_errors():
    with pytest.raises(RankDeficientError, match="zero"):
        compute_base_parameters(np.zeros((30, 10)))
    with pytest.raises(ValueError, match="rows"):
        compute_base_parameters(np.ones((5, 10)))
    with pytest.raises(ValueError, match="names"):
        compute_base_parameters(np.eye(4), names=["a"])

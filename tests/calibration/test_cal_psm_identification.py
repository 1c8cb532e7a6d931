"""The identification mathematics on the project's PSM model (rig.model.psm_dynamics.PSMDynamics)."""

import numpy as np
import pytest

from calibration.base_params import base_parameters_of, random_samples
from calibration.estimators import Identification, model_nominal
from calibration.layout import ParamLayout

from rig.model import psm_dynamics  # noqa: E402
from rig.model.psm_kinematics import DQ_MAX, Q_MAX, Q_MIN  # noqa: E402


@pytest.fixture(scope="module")
def psm():
    return psm_dynamics.PSMDynamics()


@pytest.fixture(scope="module")
def psm_base(psm):
    return base_parameters_of(psm.regressor_batch, psm, Q_MIN, Q_MAX, DQ_MAX)


def test_layout_matches_model_names(psm):
    layout = ParamLayout.of(psm)
    assert layout.n_params == psm.regressor(np.zeros(3), np.zeros(3), np.zeros(3)).shape[1]
    # Same order and kinds; the model may name its joints differently ("joint1.Fc").
    model_names = list(psm.param_names())
    assert [n.split(".")[1] for n in layout.names()] == [n.split(".")[1] for n in model_names]
    assert layout.names()[:layout.n_inertial] == model_names[:layout.n_inertial]


def test_psm_base_parameters_exact(psm):
    # (its speed, < 0.5 s, is a benchmark figure: bench/bench_identification.py)
    bp = base_parameters_of(psm.regressor_batch, psm, Q_MIN, Q_MAX, DQ_MAX)
    Q, DQ, DDQ = random_samples(50, Q_MIN, Q_MAX, DQ_MAX, seed=11)
    W = psm.regressor_batch(Q, DQ, DDQ)
    rng = np.random.default_rng(0)
    for _ in range(5):
        pi = rng.normal(size=W.shape[1])
        assert np.abs(bp.regressor(W) @ (bp.K @ pi) - W @ pi).max() <= 1e-10 * np.abs(W @ pi).max()
    assert bp.n_base == np.linalg.matrix_rank(W)
    assert bp.names == list(psm.param_names())
    assert "joint3.Fc" in bp.expressions()


def test_psm_noiseless_sdp_recovers_torques(psm, psm_base, make_trajectory):
    class Limits:
        q_min, q_max, dq_max = Q_MIN, Q_MAX, DQ_MAX
    t, q, dq, ddq = make_trajectory(Limits, seed=4, duration=20.0, rate=50.0)
    W = psm.regressor_batch(q, dq, ddq)
    pi_true = psm.standard_params()
    tau = (W @ pi_true).reshape(-1, 3)
    # Nominal off by 20 %: the SDP must still find the torques of the truth.
    nominal = model_nominal(psm) * np.random.default_rng(1).uniform(0.8, 1.2, pi_true.size)
    ident = Identification(psm_base.regressor(W), tau, psm_base, psm, nominal=nominal,
                           regressor=psm.regressor, q_check=q[::50])
    for fit in (ident.ols(), ident.sdp()):
        assert np.all(fit.relative_error < 1e-6), (fit.method, fit.relative_error)
        assert fit.checks["all_pass"], fit.checks

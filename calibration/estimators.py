"""Estimators of the dynamic parameters (thesis 5.2 and 5.4): OLS, WLS and a physically consistent SDP.

Every solution is checked.

Notation: ``Wb`` is the stacked base regressor (sample-major: rows nj*k .. nj*k+nj-1 are
sample k), ``tau`` the measured torques (n, nj), ``base`` the
:class:`~calibration.base_params.BaseParameters` that map standard parameters pi to base
ones, beta = K pi.

* **OLS**: columns of Wb normalised by their norms (eq. 5.26, P = diag(1/|W_b,c|)), solved
  with ``lstsq``; beta = P x.
* **WLS**: rows of joint j multiplied by a_j (eq. 5.25). Two choices of a_j:
  ``"residual_std"`` (default): a_j = 1 / std of the OLS residual of joint j. This is the
  Gauss-Markov weighting for errors independent between joints with per-joint variance:
  it gives each joint's equations the trust their own noise and model error deserve,
  whatever their units (N m for joints 1-2, N for the insertion joint).
  ``"tau_max"``: a_j = 1 / max |tau_j|, the thesis' choice, which only equalises ranges;
  the thesis found it worsened the conditioning (Table 5.1), as it does when one joint's
  torques are small but not less noisy.
* **SDP**: the variables are the standard parameters pi, so physical consistency is a set
  of natural constraints: each body's 4x4 pseudo-inertia J(pi_b) >= 0 (Wensing, Kim,
  Slotine 2017; it implies m >= 0, a positive definite rotational inertia and the triangle
  inequalities, which eq. 5.32 does not), m_b >= ``min_mass``, Fc >= 0, Fv >= 0, Ia >= 0,
  and optional per-body mass boxes and total-mass bounds. The objective is the weighted
  residual ||A (W pi - tau)|| = ||A (Wb K pi - tau)|| in its QR-compressed form
  (eq. 5.39-5.46: A Wb = Q1 R1, p1 = Q1^T A tau, so ||A(Wb beta - tau)||^2 =
  ||R1 beta - p1||^2 + ||p2||^2), whose size does not grow with the samples. Because the
  data cannot see the null space of W, a small pull toward the nominal pi0 is added only
  in those directions: ||N^T (pi - pi0)|| with N the orthonormal null-space basis. It
  therefore leaves the identified combinations to the data (no bias in what is observed),
  picks among the infinitely many equivalent standard sets the one nearest the nominal
  model, and keeps the problem strictly convex in pi. The objective is the Euclidean
  norm of the stacked vector [R1 K pi - p1; mu N^T (pi - pi0)], whose minimiser is that
  of the sum of squares, but which the conic solver resolves to its tolerance in the
  residual itself rather than in its square.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from calibration.base_params import BaseParameters, RankDeficientError
from calibration.layout import ParamLayout, pseudo_inertia

#: Default relative weight of the pull toward nominal in the unidentifiable directions:
#: a null-space deviation as large as |pi0| costs as much as 1e-3 of the weighted torque norm.
DEFAULT_NULL_PULL = 1e-3
#: Default lower bound on every body's mass, kg.
DEFAULT_MIN_MASS = 1e-4
#: Condition number of the column-normalised base regressor above which the data are
#: declared not exciting (well beyond the ~1e2-1e3 of a good trajectory).
MAX_CONDITION = 1e8


@dataclass
class Fit:
    """One estimate.

    beta: base parameters; pi: a standard vector with K pi = beta (the SDP's own solution;
    for LS, the inverse map eq. 5.23 with the free part from the nominal parameters);
    weights: per-joint a_j; condition: cond of the column-normalised (weighted) base
    regressor (Table 5.1); residual_norm: ||tau - Wb beta|| in mixed N m / N (Table 5.1's
    residual error); relative_error / rms: per joint on the fitted data; checks: for the
    SDP, :func:`check_physical` of its pi; for LS, ``realizable`` (:meth:`Identification.
    realizable`), ``mass_matrix_pd`` and, for information, ``inverse_map`` (the checks of the
    inverse-mapped pi); each with ``all_pass``; info: solver status and timings.
    extra: amplitudes of the extra columns (:class:`Identification`), extra_names their names.
    """

    method: str
    beta: np.ndarray
    pi: np.ndarray
    weights: np.ndarray
    condition: float | None
    residual_norm: float
    weighted_residual_norm: float
    relative_error: np.ndarray
    rms: np.ndarray
    checks: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)
    extra: np.ndarray = field(default_factory=lambda: np.zeros(0))
    extra_names: list = field(default_factory=list)

    def predict(self, Wb: np.ndarray, n_joints: int, extra_columns: np.ndarray | None = None) -> np.ndarray:
        """Predicted torques (n, nj) from a stacked base regressor (and, when the fit has
        extra columns, their stacked values for the same samples)."""
        tau = Wb @ self.beta
        if self.extra.size:
            if extra_columns is None or np.shape(extra_columns) != (Wb.shape[0], self.extra.size):
                raise ValueError(f"this fit has {self.extra.size} extra column(s) ({', '.join(self.extra_names)}): "
                                 f"give their values ({Wb.shape[0]}, {self.extra.size})")
            tau = tau + np.asarray(extra_columns, float) @ self.extra
        return tau.reshape(-1, n_joints)


def validation_errors(tau_meas: np.ndarray, tau_pred: np.ndarray) -> dict:
    """Per joint: relative error norm(tau_meas - tau_pred) / norm(tau_meas), and RMS error
    (N m or N). Both (n, nj)."""
    tau_meas = np.asarray(tau_meas, dtype=float)
    e = tau_meas - np.asarray(tau_pred, dtype=float)
    return {"relative_error": np.linalg.norm(e, axis=0) / np.linalg.norm(tau_meas, axis=0),
            "rms": np.sqrt(np.mean(e ** 2, axis=0))}


def normalised_condition(Wb: np.ndarray) -> float:
    """Condition number of Wb with its columns scaled to unit norm (eq. 5.26)."""
    n = np.linalg.norm(Wb, axis=0)
    s = np.linalg.svd(Wb / np.where(n > 0, n, 1.0), compute_uv=False)
    return float(s[0] / s[-1]) if s[-1] > 0 else float("inf")


def mass_matrix_from_regressor(regressor: Callable, q: np.ndarray, pi: np.ndarray) -> np.ndarray:
    """M(q) from any regressor: column j = Y(q, 0, e_j) pi - Y(q, 0, 0) pi.

    Gravity, offsets and friction (zero at dq = 0) cancel in the difference; the reflected
    rotor inertias (ddq columns) stay, as they belong to M.
    """
    q = np.asarray(q, dtype=float)
    n = q.shape[0]
    z = np.zeros(n)
    g = regressor(q, z, z) @ pi
    M = np.empty((n, n))
    for j in range(n):
        e = np.zeros(n)
        e[j] = 1.0
        M[:, j] = regressor(q, z, e) @ pi - g
    return 0.5 * (M + M.T)


def check_physical(pi: np.ndarray, layout, mass_matrix: Callable | None = None,
                   q_samples: np.ndarray | None = None, tol: float = 1e-7) -> dict:
    """Check a standard parameter vector for physical consistency.

    Returns ``{check: {"pass": bool, ...numbers}}`` plus ``"all_pass"``. Checks: each body's
    pseudo-inertia eigenvalues (>= -tol * max(1, |J|)), masses > 0, Fc >= 0, Fv >= 0,
    Ia >= 0 (each >= -tol), and, when ``mass_matrix(q) -> (nj, nj)`` and ``q_samples``
    (m, nj) are given, M(q) positive definite at every sample (its smallest eigenvalue).
    """
    layout = ParamLayout.of(layout)
    pi = np.asarray(pi, dtype=float)
    out: dict = {}
    eigs = {}
    ok = True
    for b, name in enumerate(layout.body_names):
        J = pseudo_inertia(pi[layout.body_slice(b)])
        lam = np.linalg.eigvalsh(J)
        eigs[name] = lam.tolist()
        ok &= bool(lam[0] >= -tol * max(1.0, np.abs(J).max()))
    out["pseudo_inertia_psd"] = {"pass": ok, "eigenvalues": eigs}
    masses = pi[layout.mass_indices]
    out["masses_positive"] = {"pass": bool(np.all(masses > 0)),
                              "masses": dict(zip(layout.body_names, masses.tolist()))}
    for key, pname in (("coulomb_nonnegative", "Fc"), ("viscous_nonnegative", "Fv"),
                       ("rotor_inertia_nonnegative", "Ia")):
        v = pi[layout.drive_indices(pname)]
        out[key] = {"pass": bool(np.all(v >= -tol)), pname: dict(zip(layout.joint_names, v.tolist()))}
    if mass_matrix is not None and q_samples is not None:
        mins = np.array([np.linalg.eigvalsh(mass_matrix(q))[0] for q in np.atleast_2d(q_samples)])
        out["mass_matrix_pd"] = {"pass": bool(np.all(mins > 0)), "min_eigenvalue": float(mins.min()),
                                 "n_configurations": int(mins.size)}
    out["all_pass"] = all(v["pass"] for v in out.values() if isinstance(v, dict))
    return out


class Identification:
    """The identification problem on one data set; ``ols()``, ``wls()``, ``sdp()`` give :class:`Fit`.

    Parameters
    ----------
    Wb : (n * nj, r)
        Stacked base regressor of the (processed) data, sample-major.
    tau : (n, nj)
        Measured torques, N m / N.
    base, layout
        Base parameters and the standard layout.
    nominal : (P,), optional
        Nominal standard parameters: the free part of LS inverse maps and the SDP's pull.
    regressor : callable, optional
        ``regressor(q, dq, ddq) -> (nj, P)``; with ``q_check`` (m, nj), every fit's M(q)
        is checked positive definite at those configurations.
    extra : (n * nj, e), optional
        Further columns outside the standard parameters (e.g. a Stribeck term), fitted
        alongside the base parameters; their amplitudes are constrained >= 0 in the SDP (and
        in the realizability test) unless ``extra_signed`` (e,) marks them as signed (the
        Fourier coefficients of a friction profile). ``extra_names`` name them.
    """

    def __init__(self, Wb: np.ndarray, tau: np.ndarray, base: BaseParameters, layout,
                 nominal: np.ndarray | None = None, regressor: Callable | None = None,
                 q_check: np.ndarray | None = None, max_condition: float = MAX_CONDITION,
                 extra: np.ndarray | None = None, extra_names: list | None = None,
                 extra_signed: list | None = None):
        self.layout = ParamLayout.of(layout)
        self.base = base
        self.tau = np.atleast_2d(np.asarray(tau, dtype=float))
        self.nj = self.tau.shape[1]
        self.Wb = np.asarray(Wb, dtype=float)
        if self.Wb.shape != (self.tau.size, base.n_base):
            raise ValueError(f"base regressor {self.Wb.shape} does not match {self.tau.shape[0]} "
                             f"samples x {self.nj} joints and {base.n_base} base parameters")
        self.y = self.tau.reshape(-1)
        self.nominal = None if nominal is None else np.asarray(nominal, dtype=float)
        self.regressor = regressor
        self.q_check = q_check
        self.r = base.n_base
        rows = self.Wb.shape[0]
        X = np.zeros((rows, 0)) if extra is None else np.asarray(extra, dtype=float).reshape(rows, -1)
        self.n_extra = X.shape[1]
        self.extra_names = (list(extra_names) if extra_names is not None
                            else [f"extra{i + 1}" for i in range(self.n_extra)])
        if len(self.extra_names) != self.n_extra:
            raise ValueError(f"{self.n_extra} extra columns but {len(self.extra_names)} names")
        signed = np.zeros(self.n_extra, bool) if extra_signed is None else np.asarray(extra_signed, bool)
        if signed.shape != (self.n_extra,):
            raise ValueError(f"{self.n_extra} extra columns but {signed.size} signed flags")
        #: indices of the extra columns whose amplitude must be >= 0
        self.extra_nonnegative = np.flatnonzero(~signed)
        # The design matrix actually solved: base regressor, then the extra columns.
        self.Wx = np.hstack([self.Wb, X]) if self.n_extra else self.Wb
        self.col_norms = np.linalg.norm(self.Wx, axis=0)
        self._check_excitation(max_condition)
        self._ols: Fit | None = None

    @classmethod
    def from_model(cls, model, data, base: BaseParameters, nominal=None, n_check: int = 50,
                   seed: int = 0, **kw) -> "Identification":
        """Build from a model with ``regressor_batch`` and processed ``JointData`` (with ddq)."""
        if data.ddq is None:
            raise ValueError(f"{data.source}: accelerations missing: process the data first "
                             "(calibration.datasets.processed)")
        W = model.regressor_batch(data.q, data.dq, data.ddq)
        rng = np.random.default_rng(seed)
        idx = rng.choice(data.n_samples, size=min(n_check, data.n_samples), replace=False)
        if nominal is None:
            nominal = model_nominal(model)
        return cls(base.regressor(W), data.tau, base, ParamLayout.of(model), nominal=nominal,
                   regressor=model.regressor, q_check=data.q[np.sort(idx)], **kw)

    # -- excitation ---------------------------------------------------------------------------
    def _check_excitation(self, max_condition: float):
        names = self.base.expressions(digits=3) + self.extra_names
        zero = np.flatnonzero(self.col_norms == 0)
        if zero.size:
            raise RankDeficientError(
                "the trajectory does not excite base parameter(s) "
                + "; ".join(f"#{i + 1} [{names[i]}]" for i in zero)
                + ": their regressor columns are zero (a joint that does not move, or never "
                  "reverses or accelerates): use an exciting trajectory")
        Wn = self.Wx / self.col_norms
        _, s, Vt = np.linalg.svd(Wn, full_matrices=False)
        self.condition_ls = float(s[0] / s[-1]) if s[-1] > 0 else float("inf")
        if not self.condition_ls < max_condition:
            v = Vt[-1]
            worst = np.argsort(np.abs(v))[::-1][:3]
            raise RankDeficientError(
                f"the trajectory does not excite the base parameters independently: the "
                f"column-normalised base regressor has condition number {self.condition_ls:.3g} "
                f"(limit {max_condition:.0e}); the nearly dependent combination involves "
                + ", ".join(f"#{i + 1} [{names[i]}]" for i in worst)
                + ": use an optimised excitation trajectory (calibration.excitation)")

    # -- helpers ------------------------------------------------------------------------------
    def _row_weights(self, a: np.ndarray) -> np.ndarray:
        return np.tile(a, self.tau.shape[0])

    def _weights(self, weighting) -> np.ndarray:
        if isinstance(weighting, str):
            if weighting == "residual_std":
                o = self.ols()
                r = (self.y - self.Wx @ np.concatenate([o.beta, o.extra])).reshape(-1, self.nj)
                sd = r.std(axis=0)
                # A joint fitted to rounding level would get an infinite weight.
                floor = 1e-9 * np.abs(self.tau).max(axis=0) + 1e-300
                return 1.0 / np.maximum(sd, floor)
            if weighting == "tau_max":
                return 1.0 / np.abs(self.tau).max(axis=0)
            if weighting == "none":
                return np.ones(self.nj)
            raise ValueError(f"unknown weighting {weighting!r}: 'residual_std', 'tau_max' or 'none'")
        a = np.asarray(weighting, dtype=float)
        if a.shape != (self.nj,) or np.any(a <= 0):
            raise ValueError(f"weights must be {self.nj} positive numbers, got {a}")
        return a

    def _fit(self, method, theta, a, cond, pi=None, info=None) -> Fit:
        theta = np.asarray(theta, dtype=float)
        beta, extra = theta[:self.r], theta[self.r:]
        pred = self.Wx @ theta
        r = self.y - pred
        if pi is None:
            pi = self.base.standard_from_base(beta, self.nominal)
        ve = validation_errors(self.tau, pred.reshape(-1, self.nj))
        fit = Fit(method, beta, pi, a, cond, float(np.linalg.norm(r)),
                  float(np.linalg.norm(r * self._row_weights(a))), ve["relative_error"], ve["rms"],
                  info=info or {}, extra=extra, extra_names=list(self.extra_names))
        mm = None
        if self.regressor is not None and self.q_check is not None:
            mm = lambda q: mass_matrix_from_regressor(self.regressor, q, pi)  # noqa: E731
        physical = check_physical(pi, self.layout, mm, self.q_check)
        if self.n_extra:
            physical["extra_nonnegative"] = {"pass": bool(np.all(extra[self.extra_nonnegative] >= -1e-9)),
                                             "values": dict(zip(self.extra_names, extra.tolist()))}
            physical["all_pass"] = all(v["pass"] for v in physical.values() if isinstance(v, dict))
        if method == "sdp":
            fit.checks = physical
            return fit
        # An LS estimate fixes only beta: its standard vector is one of infinitely many, so
        # what decides is whether *some* consistent pi gives the same torques (realizable),
        # and M(q), which depends on beta alone. The inverse-mapped pi's own checks are
        # reported for information.
        checks = {"realizable": self.realizable(beta, extra=extra)}
        physical.pop("extra_nonnegative", None)  # LS extras are judged by realizability
        if "mass_matrix_pd" in physical:
            checks["mass_matrix_pd"] = physical.pop("mass_matrix_pd")
        physical.pop("all_pass")
        checks["all_pass"] = all(v["pass"] for v in checks.values())
        checks["inverse_map"] = physical
        fit.checks = checks
        return fit

    # -- estimators ---------------------------------------------------------------------------
    def ols(self) -> Fit:
        """Ordinary least squares on the column-normalised base regressor (eq. 5.24, 5.26)."""
        if self._ols is None:
            t0 = time.perf_counter()
            x, *_ = np.linalg.lstsq(self.Wx / self.col_norms, self.y, rcond=None)
            beta = x / self.col_norms
            self._ols = self._fit("ols", beta, np.ones(self.nj), self.condition_ls,
                                  info={"seconds": time.perf_counter() - t0})
        return self._ols

    def wls(self, weighting="residual_std") -> Fit:
        """Weighted least squares (eq. 5.25): ``weighting`` is "residual_std" (default, see
        the module docstring), "tau_max" (thesis) or an array of per-joint a_j."""
        t0 = time.perf_counter()
        a = self._weights(weighting)
        w = self._row_weights(a)
        Aw = self.Wx * w[:, None]
        n = np.linalg.norm(Aw, axis=0)
        x, *_ = np.linalg.lstsq(Aw / n, self.y * w, rcond=None)
        beta = x / n
        cond = normalised_condition(Aw)
        return self._fit("wls", beta, a, cond,
                         info={"weighting": weighting if isinstance(weighting, str) else "given",
                               "seconds": time.perf_counter() - t0})

    def _compressed(self, a):
        """R1, p1 and the norm of p2 of eq. 5.39-5.43 for weights a."""
        w = self._row_weights(a)
        Q1, R1 = np.linalg.qr(self.Wx * w[:, None])
        wy = self.y * w
        p1 = Q1.T @ wy
        p2sq = max(float(wy @ wy - p1 @ p1), 0.0)
        return R1, p1, np.sqrt(p2sq)

    def _constraints(self, cp, pi, min_mass, mass_bounds, total_mass):
        L = self.layout
        cons = []
        T = _pseudo_inertia_map()
        for b in range(L.n_bodies):
            J = cp.reshape(T @ pi[L.body_slice(b)], (4, 4), order="F")
            cons.append(J >> 0)
        masses = pi[L.mass_indices]
        cons.append(masses >= min_mass)
        if mass_bounds:
            for name, (lo, hi) in mass_bounds.items():
                i = L.mass_index(L.body_names.index(name))
                if lo is not None:
                    cons.append(pi[i] >= lo)
                if hi is not None:
                    cons.append(pi[i] <= hi)
        if total_mass is not None:
            lo, hi = total_mass
            if lo is not None:
                cons.append(cp.sum(masses) >= lo)
            if hi is not None:
                cons.append(cp.sum(masses) <= hi)
        for name in ("Fc", "Fv", "Ia"):
            cons.append(pi[L.drive_indices(name)] >= 0)
        return cons

    def sdp(self, weighting="residual_std", null_pull: float = DEFAULT_NULL_PULL,
            min_mass: float = DEFAULT_MIN_MASS, mass_bounds: dict | None = None,
            total_mass: tuple | None = None, tol: float = 1e-9) -> Fit:
        """Physically consistent weighted LS over the standard parameters (module docstring).

        ``weighting`` as in :meth:`wls`; ``null_pull`` the relative weight of the pull toward
        the nominal parameters in unidentifiable directions (toward zero without a nominal);
        ``min_mass`` kg; ``mass_bounds`` {body: (lo, hi)} kg; ``total_mass`` (lo, hi) kg;
        ``tol`` the Clarabel gap and feasibility tolerances.
        """
        import cvxpy as cp

        t0 = time.perf_counter()
        a = self._weights(weighting)
        R1, p1, p2n = self._compressed(a)
        K, N = self.base.K, self.base.null_basis
        P = K.shape[1]
        pi0 = self.nominal if self.nominal is not None else np.zeros(P)
        # Scale so that the objective is O(1) for the solver.
        s = 1.0 / max(np.linalg.norm(p1), 1e-300)
        mu = null_pull / max(np.linalg.norm(pi0), 1.0)
        pi = cp.Variable(P)
        resid = (s * (R1[:, :self.r] @ K)) @ pi - s * p1
        ex = None
        if self.n_extra:
            ex = cp.Variable(self.n_extra)
            resid = resid + (s * R1[:, self.r:]) @ ex
        terms = [resid]
        if N.shape[1]:
            terms.append(mu * (N.T @ pi - N.T @ pi0))
        objective = cp.Minimize(cp.norm(cp.hstack(terms), 2))
        cons = self._constraints(cp, pi, min_mass, mass_bounds, total_mass)
        if ex is not None and self.extra_nonnegative.size:
            cons.append(ex[self.extra_nonnegative] >= 0)
        prob = cp.Problem(objective, cons)
        t1 = time.perf_counter()
        prob.solve(solver=cp.CLARABEL, tol_gap_abs=tol, tol_gap_rel=tol, tol_feas=tol,
                   tol_ktratio=tol * 1e-2, max_iter=200)
        t2 = time.perf_counter()
        if pi.value is None or prob.status not in ("optimal", "optimal_inaccurate"):
            raise RuntimeError(f"SDP identification failed: solver status {prob.status!r}; check "
                               "that the bounds (min_mass, mass_bounds, total_mass) are compatible")
        piv = np.asarray(pi.value, dtype=float)
        theta = K @ piv
        if ex is not None:
            exv = np.asarray(ex.value, dtype=float).copy()
            exv[self.extra_nonnegative] = np.maximum(exv[self.extra_nonnegative], 0.0)
            theta = np.concatenate([theta, exv])
        cond = normalised_condition(self.Wx * self._row_weights(a)[:, None])
        info = {"status": prob.status, "solver": "CLARABEL", "iterations": prob.solver_stats.num_iters,
                "compile_seconds": t1 - t0, "solve_seconds": t2 - t1,
                "seconds": time.perf_counter() - t0, "null_pull": null_pull, "min_mass": min_mass,
                "compressed_rows": int(R1.shape[0]), "residual_p2": p2n,
                "weighting": weighting if isinstance(weighting, str) else "given"}
        return self._fit("sdp", theta, a, cond, pi=piv, info=info)

    def realizable(self, beta: np.ndarray, weighting="none", min_mass: float = 0.0,
                   rel_tol: float = 1e-6, extra: np.ndarray | None = None) -> dict:
        """Is there a physically consistent pi (pseudo-inertias PSD, masses >= ``min_mass``,
        Fc, Fv, Ia >= 0) with the torques of ``beta`` on these data?

        Solves min ||R1 (K pi - beta)|| over consistent pi: the extra (weighted) residual a
        physical model must accept. ``pass`` when it is below ``rel_tol`` of ||R1 beta||.
        This is the right test for LS solutions: their standard vector is not unique, so a
        failing check of one inverse-mapped pi does not by itself prove infeasibility.
        """
        import cvxpy as cp

        a = self._weights(weighting)
        R1, _, _ = self._compressed(a)
        K = self.base.K
        theta = np.concatenate([np.asarray(beta, dtype=float),
                                np.zeros(self.n_extra) if extra is None else np.asarray(extra, dtype=float)])
        target = R1 @ theta
        s = 1.0 / max(np.linalg.norm(target), 1e-300)
        pi = cp.Variable(K.shape[1])
        model = (s * (R1[:, :self.r] @ K)) @ pi
        cons = self._constraints(cp, pi, min_mass, None, None)
        if self.n_extra:
            ex = cp.Variable(self.n_extra)
            model = model + (s * R1[:, self.r:]) @ ex
            if self.extra_nonnegative.size:
                cons.append(ex[self.extra_nonnegative] >= 0)
        prob = cp.Problem(cp.Minimize(cp.norm(model - s * target, 2)), cons)
        with warnings.catch_warnings():
            # "optimal_inaccurate" near a zero optimum is expected here; the status is returned.
            warnings.simplefilter("ignore", UserWarning)
            prob.solve(solver=cp.CLARABEL, tol_gap_abs=1e-10, tol_gap_rel=1e-10, tol_feas=1e-10)
        gap = float(prob.value) if prob.value is not None else float("inf")
        return {"pass": bool(gap <= rel_tol), "relative_gap": gap, "status": prob.status}


def model_nominal(model) -> np.ndarray | None:
    """The model's nominal standard parameters (``nominal_params()``, or ``standard_params()``)."""
    for name in ("nominal_params", "standard_params"):
        if hasattr(model, name):
            return np.asarray(getattr(model, name)(), dtype=float)
    return None


def _pseudo_inertia_map() -> np.ndarray:
    """(16, 10) matrix T with vec_F(J) = T @ [m, hx, hy, hz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]."""
    T = np.zeros((16, 10))
    for k in range(10):
        e = np.zeros(10)
        e[k] = 1.0
        T[:, k] = pseudo_inertia(e).reshape(-1, order="F")
    return T

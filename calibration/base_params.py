"""Numeric base parameters (thesis 5.1, eq. 5.7-5.23) by pivoted QR of a stacked regressor.

Given the stacked regressor W (rows: samples x joints, columns: standard parameters pi) of
random, exciting (q, dq, ddq) samples, a column-pivoted QR of the column-normalised W finds
r = rank(W) independent columns ``independent``; every other column is a fixed linear
combination of them, W_d = W_b X. Hence for any pi

    W pi = W_b (pi_b + X pi_d) = W_b beta,   beta = K pi,   K = [I | X] (re-ordered),

which is eq. 5.22 without the SVD detour. The null space of W (directions of pi the torques
never see) is spanned by the columns of [-X; I]; an orthonormal basis ``null_basis`` is what
the SDP uses to pull toward nominal values, and ``standard_from_base(beta, free)`` is the
inverse map of eq. 5.23 with the free part pi_d.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.linalg

from calibration.layout import ParamLayout


class RankDeficientError(ValueError):
    """The data do not excite some base parameter: the base regressor is rank deficient."""


@dataclass
class BaseParameters:
    """Result of :func:`compute_base_parameters`.

    Attributes
    ----------
    independent : (r,) int
        Columns of the standard regressor kept as the base regressor W_b = W[:, independent].
    dependent : (P - r,) int
        The other columns, sorted.
    K : (r, P)
        Regrouping matrix, beta = K pi (eq. 5.22), W_b K = W for every sample.
    X : (r, P - r)
        W[:, dependent] = W_b X.
    null_basis : (P, P - r)
        Orthonormal basis of the null space of W (unidentifiable directions of pi).
    names : list[str]
        Names of the standard parameters.
    tolerance : float
        Relative rank tolerance used on |R_ii| / |R_00| of the normalised QR.
    """

    independent: np.ndarray
    dependent: np.ndarray
    K: np.ndarray
    X: np.ndarray
    null_basis: np.ndarray
    names: list[str]
    tolerance: float
    singular_ratio: float

    @property
    def n_base(self) -> int:
        return len(self.independent)

    @property
    def n_standard(self) -> int:
        return self.K.shape[1]

    def base_from_standard(self, pi: np.ndarray) -> np.ndarray:
        """beta = K pi (eq. 5.22)."""
        return self.K @ np.asarray(pi, dtype=float)

    def standard_from_base(self, beta: np.ndarray, free: np.ndarray | None = None) -> np.ndarray:
        """One standard vector pi with K pi = beta (eq. 5.23).

        ``free`` gives the dependent parameters pi_d, either as a (P - r,) vector or as a full
        (P,) standard vector (e.g. the nominal one) from which they are taken; zero if None.
        """
        beta = np.asarray(beta, dtype=float)
        P = self.n_standard
        if free is None:
            pid = np.zeros(len(self.dependent))
        else:
            free = np.asarray(free, dtype=float)
            pid = free[self.dependent] if free.shape == (P,) else free
        pi = np.empty(P)
        pi[self.dependent] = pid
        pi[self.independent] = beta - self.X @ pid
        return pi

    def regressor(self, W: np.ndarray) -> np.ndarray:
        """Base regressor W_b from a standard one."""
        return W[:, self.independent]

    def expressions(self, digits: int = 6, drop_below: float = 1e-8) -> list[str]:
        """Human-readable base parameters, e.g. ``"tool.m + 0.5 counterweight2.m"``.

        Coefficients with magnitude below ``drop_below`` are dropped (numerical dust of the
        QR), the rest rounded to ``digits`` significant digits.
        """
        out = []
        for i in range(self.n_base):
            terms = []
            for j in np.flatnonzero(np.abs(self.K[i]) >= drop_below):
                c = float(f"{self.K[i, j]:.{digits}g}")
                terms.append((c, self.names[j]))
            # The kept standard parameter first, the regrouped ones after.
            terms.sort(key=lambda cn: (cn[1] != self.names[self.independent[i]],))
            s = ""
            for c, n in terms:
                mag = abs(c)
                coef = "" if mag == 1.0 else f"{mag:g} "
                if not s:
                    s = ("-" if c < 0 else "") + coef + n
                else:
                    s += (" - " if c < 0 else " + ") + coef + n
            out.append(s)
        return out


def random_samples(n: int, q_min, q_max, dq_max, ddq_max=None, seed: int = 0):
    """Uniform random (q, dq, ddq) samples, (n, nj) each, within the given limits.

    Base parameters are a property of the model, not of a trajectory, so they are found on
    random samples that excite everything the model can excite.
    """
    rng = np.random.default_rng(seed)
    q_min, q_max, dq_max = (np.asarray(x, dtype=float) for x in (q_min, q_max, dq_max))
    ddq_max = 5.0 * dq_max if ddq_max is None else np.asarray(ddq_max, dtype=float)
    nj = q_min.shape[0]
    Q = rng.uniform(q_min, q_max, (n, nj))
    DQ = rng.uniform(-dq_max, dq_max, (n, nj))
    DDQ = rng.uniform(-ddq_max, ddq_max, (n, nj))
    return Q, DQ, DDQ


def compute_base_parameters(W: np.ndarray, names=None, layout: ParamLayout | None = None,
                            tol: float = 1e-9) -> BaseParameters:
    """Base parameters of a stacked standard regressor W (M, P) of random exciting samples.

    ``tol`` is the relative rank tolerance on the diagonal of R of the column-normalised W
    (1e-9: well above double rounding of a ~1e3-row product, well below any physical
    parameter's relative contribution). Columns with zero norm are unidentifiable outright.
    """
    W = np.asarray(W, dtype=float)
    if W.ndim != 2:
        raise ValueError(f"regressor must be 2-D, got shape {W.shape}")
    M, P = W.shape
    if names is None:
        names = ParamLayout.of(layout).names() if layout is not None else [f"p{i}" for i in range(P)]
    names = list(names)
    if len(names) != P:
        raise ValueError(f"{len(names)} parameter names for {P} regressor columns")
    if M < P:
        raise ValueError(f"regressor has {M} rows for {P} parameters: use more samples")
    norms = np.linalg.norm(W, axis=0)
    nz = norms > 1e-12 * max(norms.max(), 1e-300)
    cols = np.flatnonzero(nz)
    Wn = W[:, cols] / norms[cols]
    _, R, perm = scipy.linalg.qr(Wn, mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    r = int(np.sum(d > tol * d[0])) if d.size else 0
    if r == 0:
        raise RankDeficientError("the regressor is zero: nothing is identifiable")
    ind_local = perm[:r]
    # Normalised relation: Wn[:, dep] = Wn[:, ind] @ Xn with Xn = R11^-1 R12.
    Xn = scipy.linalg.solve_triangular(R[:r, :r], R[:r, r:])
    independent = cols[ind_local]
    dep_nonzero = cols[perm[r:]]
    # Undo the column scaling: W_d = W_b diag(n_b)^-1 Xn diag(n_d).
    Xd = (Xn / norms[independent][:, None]) * norms[dep_nonzero][None, :]
    # Order the base parameters by standard index, so they read like the layout.
    order = np.argsort(independent)
    independent = independent[order]
    Xd = Xd[order]
    dependent = np.setdiff1d(np.arange(P), independent)
    X = np.zeros((r, len(dependent)))
    pos = {c: k for k, c in enumerate(dependent)}
    for k, c in enumerate(dep_nonzero):
        X[:, pos[c]] = Xd[:, k]
    K = np.zeros((r, P))
    K[np.arange(r), independent] = 1.0
    K[:, dependent] = X
    N = np.zeros((P, len(dependent)))
    N[independent] = -X
    N[dependent, np.arange(len(dependent))] = 1.0
    null_basis = np.linalg.qr(N)[0] if N.shape[1] else N
    ratio = float(d[r - 1] / d[0])
    return BaseParameters(independent, dependent, K, X, null_basis, names, tol, ratio)


def base_parameters_of(regressor_batch: Callable, layout, q_min, q_max, dq_max, ddq_max=None,
                       n_samples: int | None = None, seed: int = 0, tol: float = 1e-9) -> BaseParameters:
    """Base parameters of a model from its ``regressor_batch(Q, DQ, DDQ) -> (N*nj, P)``.

    ``layout`` is a :class:`ParamLayout` or the model itself (its names are then used).

    Samples are random within the limits; ``n_samples`` defaults to enough rows to be
    over-determined several times (max(200, 2 P / nj)).
    """
    # A model that names its own parameters (``param_names()``) keeps its names.
    names = list(layout.param_names()) if hasattr(layout, "param_names") else None
    layout = ParamLayout.of(layout)
    nj = layout.n_joints
    if n_samples is None:
        n_samples = max(200, int(np.ceil(2 * layout.n_params / nj)))
    Q, DQ, DDQ = random_samples(n_samples, q_min, q_max, dq_max, ddq_max, seed)
    W = regressor_batch(Q, DQ, DDQ)
    return compute_base_parameters(W, names=names, layout=layout, tol=tol)

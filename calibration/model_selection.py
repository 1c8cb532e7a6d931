"""Choosing what the linear fit cannot: the gravity direction and the Coulomb sigmoid slope.

Both enter the regressor non-linearly, so they are chosen by an outer search that scores
each candidate by the best linear (least-squares) fit it allows on the training data.

**Gravity direction.** A PSM on its set-up joints is tilted, so on recorded data the
gravity vector in frame 0 is unknown. The regressor is linear in gravity (gravity is a
base acceleration in the recursive Newton-Euler sums):

    W(g) = W_0 + gx W_x + gy W_y + gz W_z

with W_0 the regressor of the motion without gravity and W_k the gravity-only regressor for
a unit vector along axis k (zero velocity and acceleration, drive columns zeroed). The
Gram matrices of [W_0, W_x, W_y, W_z, tau] are formed once; the least-squares residual of
any direction is then a small (P x P) solve, so the whole sphere can be scanned. The
magnitude is kept at ``|g|`` (9.81 m/s^2): it is not separable from the masses.

A least-squares fit cannot tell g from -g well: flipping gravity is almost absorbed by
flipping the first mass moments (only the masses shared with the inertial terms resist).
The search therefore returns the best direction of each hemisphere, and the caller decides
between the two with a physically consistent fit (SDP), which does see the sign.

**Coulomb slope.** The smooth sign tanh(a dq / 2) of eq. 4.14 with a = 400 s/rad is a
controller choice; for identification a gentler transition also models the rounded
friction reversal the real joints show. a is scanned on a grid with the same scores.

Scores are the sum over joints of squared relative residuals, ||r_j||^2 / ||tau_j||^2,
so that N m and N joints count alike (the relative error of the validation tables).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import scipy.optimize

STANDARD_GRAVITY = 9.81  # m/s^2, the magnitude of the model's default gravity

#: Slopes a (s/rad or s/m) of tanh(a dq / 2) tried by default; 400 is the thesis' value.
DEFAULT_SLOPES = (10.0, 20.0, 50.0, 100.0, 200.0, 400.0)


def fibonacci_sphere(n: int) -> np.ndarray:
    """n nearly uniform unit vectors (n, 3)."""
    i = np.arange(n) + 0.5
    polar = np.arccos(1.0 - 2.0 * i / n)
    azimuth = np.pi * (1.0 + 5 ** 0.5) * i
    return np.column_stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)])


def _unit_from_angles(angles: np.ndarray) -> np.ndarray:
    polar, azimuth = angles
    return np.array([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)])


def _angles_from_unit(u: np.ndarray) -> np.ndarray:
    return np.array([np.arccos(np.clip(u[2], -1.0, 1.0)), np.arctan2(u[1], u[0])])


@dataclass
class GravityCandidate:
    """One direction: unit vector (frame 0), tilt from the model's -z (deg), and the
    per-joint relative residual of the least-squares fit it allows on the training data."""

    direction: np.ndarray
    tilt_deg: float
    relative_residual: np.ndarray
    score: float

    def to_dict(self) -> dict:
        return {"direction": self.direction.tolist(), "tilt_deg": self.tilt_deg,
                "relative_residual": self.relative_residual.tolist(), "score": self.score}


@dataclass
class SearchResult:
    """Best slope and the best gravity direction of each hemisphere (``candidates[0]`` best)."""

    slope: float
    magnitude: float
    candidates: list[GravityCandidate]
    slope_scores: dict = field(default_factory=dict)
    nominal: GravityCandidate | None = None
    seconds: float = 0.0

    def gravity(self, k: int = 0) -> np.ndarray:
        return self.magnitude * self.candidates[k].direction


class GravitySlopeSearch:
    """Least-squares scores of (gravity direction, Coulomb slope) on one data set.

    Parameters
    ----------
    make_model : callable
        ``make_model(gravity (3,), slope) -> model`` with ``regressor_batch`` (sample-major,
        drive columns [Fc, Fv, Fo, Ia] per joint after ``n_inertial`` inertial columns).
    q, dq, ddq, tau : (n, nj)
        Processed training data (SI).
    n_inertial : int
        Number of inertial (body) columns; drive columns follow, 4 per joint.
    mask : (n, nj) bool, optional
        Joint samples to use; the others become zero equations (0 = 0), which leave the
        least-squares solution untouched (e.g. a stuck joint whose effort no model gives).
    rows : callable, optional
        ``rows(fn) -> (n * nj, p)``: how a function of the motion ``fn(q, dq, ddq)`` (stacked
        sample-major) becomes equation rows, e.g. ``JointData.context.rows`` for parallel
        filtering; by default ``fn`` of the given q, dq, ddq.
    extra : (n * nj, e), optional
        Further equation columns independent of gravity and of the slope (e.g. catalogue
        effects identified with the rigid body), fitted beside the model's.
    """

    def __init__(self, make_model: Callable, q, dq, ddq, tau, n_inertial: int, mask=None, rows=None, extra=None):
        self.q, self.dq, self.ddq = (np.asarray(x, float) for x in (q, dq, ddq))
        self._rows = rows if rows is not None else (lambda fn: fn(self.q, self.dq, self.ddq))
        self.tau = np.asarray(tau, float)
        self.mask = None if mask is None else np.asarray(mask, bool)
        if self.mask is not None:
            self.tau = self.tau * self.mask
        self.nj = self.tau.shape[1]
        self.n_inertial = int(n_inertial)
        # Motion without gravity; the Coulomb columns are replaced per slope below.
        W0 = self._rows(make_model(np.zeros(3), 400.0).regressor_batch)
        n_model = W0.shape[1]
        if extra is not None:
            W0 = np.hstack([W0, np.asarray(extra, float)])
        self.P = W0.shape[1]
        blocks = [W0]
        for k in range(3):
            g = np.zeros(3)
            g[k] = 1.0
            model_k = make_model(g, 400.0)
            Wk = self._rows(lambda q, dq, ddq: model_k.regressor_batch(q, np.zeros_like(dq), np.zeros_like(ddq)))
            Wk[:, self.n_inertial:] = 0.0  # the offset column (1) belongs to W0 only
            blocks.append(np.hstack([Wk, np.zeros((Wk.shape[0], self.P - n_model))]))
        if self.mask is not None:
            rows = self.mask.reshape(-1)
            blocks = [B * rows[:, None] for B in blocks]
        self._blocks = blocks
        norms = np.linalg.norm(self.tau, axis=0)
        if np.any(norms == 0):
            raise ValueError(f"joint(s) {(np.flatnonzero(norms == 0) + 1).tolist()} have no torque samples "
                             "to fit (all zero or masked out)")
        self._row_scale = 1.0 / norms
        self._fc_cols = self.n_inertial + 4 * np.arange(self.nj)
        self._slope_grams: dict[float, list[np.ndarray]] = {}

    def _grams(self, slope: float) -> list[np.ndarray]:
        """Per-joint Gram matrices of [W0 | Wx | Wy | Wz | tau] (weighted by 1/||tau_j||)."""
        if slope not in self._slope_grams:
            W0 = self._blocks[0].copy()
            sigmoid = self._rows(lambda q, dq, ddq: np.tanh(0.5 * slope * dq).reshape(-1, 1))[:, 0]
            for j in range(self.nj):
                W0[j::self.nj, self._fc_cols[j]] = sigmoid[j::self.nj] * (
                    1.0 if self.mask is None else self.mask[:, j])
            grams = []
            for j in range(self.nj):
                B = np.hstack([W0[j::self.nj]] + [Wk[j::self.nj] for Wk in self._blocks[1:]]
                              + [self.tau[:, j:j + 1]]) * self._row_scale[j]
                grams.append(B.T @ B)
            self._slope_grams[slope] = grams
        return self._slope_grams[slope]

    def _solve(self, gravity, slope):
        """Least-squares solution x and the reduced per-joint Grams of [W(g) | tau]."""
        grams = self._grams(slope)
        P = self.P
        c = np.concatenate([[1.0], np.asarray(gravity, float)])
        # [W(g) | tau] = [W0 | Wx | Wy | Wz | tau] E: reduce the Gram blockwise, O(16 P^2).
        reduced = []
        for G in grams:
            G4 = G[:4 * P, :4 * P].reshape(4, P, 4, P)
            A = np.einsum("a,apbq,b->pq", c, G4, c)
            b = G[:4 * P, 4 * P].reshape(4, P).T @ c
            reduced.append((A, b, G[4 * P, 4 * P]))
        A = sum(r[0] for r in reduced)
        b = sum(r[1] for r in reduced)
        s = np.sqrt(np.diag(A))
        s[s == 0] = 1.0
        x = np.linalg.lstsq(A / np.outer(s, s), b / s, rcond=1e-12)[0] / s
        return x, reduced

    def residuals(self, gravity: np.ndarray, slope: float) -> np.ndarray:
        """Per-joint relative residual ||r_j|| / ||tau_j|| of the least-squares fit (lstsq,
        minimum norm, so unidentifiable directions do no harm)."""
        x, reduced = self._solve(gravity, slope)
        out = np.array([tt - 2.0 * b @ x + x @ A @ x for A, b, tt in reduced])
        return np.sqrt(np.maximum(out, 0.0))

    def score(self, gravity, slope) -> float:
        return float(np.sum(self.residuals(gravity, slope) ** 2))

    def search(self, slopes=DEFAULT_SLOPES, magnitude: float = STANDARD_GRAVITY, n_directions: int = 400,
               fixed_gravity: np.ndarray | None = None, nominal_direction=(0.0, 0.0, -1.0)) -> SearchResult:
        """Scan slopes (and, unless ``fixed_gravity`` is given, directions); refine locally.

        Returns the best slope and, for gravity, the best direction of each hemisphere
        (the sign is left to a physically consistent fit, see the module docstring).
        """
        import time

        t0 = time.perf_counter()
        nominal_u = np.asarray(nominal_direction, float)
        nominal_u = nominal_u / np.linalg.norm(nominal_u)
        slopes = [float(s) for s in slopes]
        if fixed_gravity is not None:
            g = np.asarray(fixed_gravity, float)
            scores = {s: self.score(g, s) for s in slopes}
            best = min(scores, key=scores.get)
            u = g / np.linalg.norm(g)
            cand = self._candidate(u, np.linalg.norm(g), best, nominal_u)
            return SearchResult(best, float(np.linalg.norm(g)), [cand], scores, cand, time.perf_counter() - t0)
        # Slopes on a coarse sphere (the surface is smooth and flat), then the best slope
        # on the full one.
        coarse = fibonacci_sphere(max(n_directions // 3, 24))
        slope_scores = {s: float(min(self.score(magnitude * u, s) for u in coarse)) for s in slopes}
        slope = min(slope_scores, key=slope_scores.get)
        U = fibonacci_sphere(n_directions)
        sc = np.array([self.score(magnitude * u, slope) for u in U])
        first = int(np.argmin(sc))
        other = [k for k in np.argsort(sc) if U[k] @ U[first] < 0][0]
        cands = []
        for k in (first, other):
            res = scipy.optimize.minimize(lambda a: self.score(magnitude * _unit_from_angles(a), slope),
                                          _angles_from_unit(U[k]), method="Nelder-Mead",
                                          options={"xatol": 1e-4, "fatol": 1e-12, "maxiter": 300})
            u = _unit_from_angles(res.x)
            # Keep the refined point in its hemisphere: the two must stay distinct candidates.
            if k == other and u @ cands[0].direction >= 0:
                u = U[k]
            cands.append(self._candidate(u, magnitude, slope, nominal_u))
        cands.sort(key=lambda c: c.score)
        nominal = self._candidate(nominal_u, magnitude, slope, nominal_u)
        return SearchResult(slope, magnitude, cands, slope_scores, nominal, time.perf_counter() - t0)

    def _candidate(self, u, magnitude, slope, nominal_u) -> GravityCandidate:
        r = self.residuals(magnitude * u, slope)
        tilt = float(np.degrees(np.arccos(np.clip(u @ nominal_u, -1.0, 1.0))))
        return GravityCandidate(np.asarray(u, float), tilt, r, float(np.sum(r ** 2)))

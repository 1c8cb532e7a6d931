"""Optimal Fourier-series excitation trajectories (thesis 5.3, eq. 5.27-5.30).

    q_i(t) = sum_{l=1..L} a_il/(w l) sin(w l t) - b_il/(w l) cos(w l t) + q_i0        (5.28)

**Frequency unit.** The thesis gives the fundamental as "w = 0.13 rad/s" in the text but
"w [Hz]" in Table 5.1 and "w = 0.13 Hz" in the text about Figure 5.1. With 0.13 rad/s the
fundamental period (48 s) would exceed the 30 s trajectory and the fifth harmonic would be
at 0.1 Hz; the recorded WPI data (``shared/data/wpi-psm/one_results.csv``, the same
package's 30 s trajectory) has its spectral lines at 0.154 Hz and its multiples up to the
fifth. So the fundamental here is a frequency in Hz, ``frequency_hz=0.13`` by default
(w = 2 pi 0.13 rad/s, period 7.7 s, ~3.9 periods in 30 s, harmonics 0.13-0.65 Hz, well
under the 3.5 Hz processing filter).

**At rest at both ends.** 30 s is not a whole number of periods, so periodicity alone does
not bring the arm back to rest. Per joint, the five linear conditions dq(0) = dq(T) = 0,
ddq(0) = ddq(T) = 0 and q(T) = q(0) on the 2L coefficients (a, b) are solved once: the
coefficients are c = Z z with Z a basis of their null space, and the optimiser works on z.
Every trajectory it tries therefore starts and ends at rest at the same position exactly.

**Limits.** q, dq (and ddq if given) limits are linear constraints in (z, q0) on a grid of
constraint samples, with a small margin for what happens between them; the result is then
checked at every sample of the full trajectory and, if needed, its motion about the mean
is scaled down (which preserves the rest conditions) until it is within the limits.

**Objective.** log cond of the column-normalised base regressor (eq. 5.26-5.27) on a
subsample of the trajectory; SLSQP from several seeded starts; the condition on the full
trajectory is reported at the end.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import scipy.linalg
import scipy.optimize

DEFAULT_FREQUENCY_HZ = 0.13
DEFAULT_HARMONICS = 5
DEFAULT_DURATION = 30.0
DEFAULT_RATE = 200.0


@dataclass
class FourierTrajectory:
    """Eq. 5.28 with fundamental ``frequency_hz`` (w = 2 pi f rad/s); a, b (nj, L) in
    rad/s or m/s (the velocity amplitudes), q0 (nj,) rad or m, duration s."""

    frequency_hz: float
    a: np.ndarray
    b: np.ndarray
    q0: np.ndarray
    duration: float

    @property
    def n_joints(self) -> int:
        return self.a.shape[0]

    @property
    def w(self) -> float:
        return 2.0 * np.pi * self.frequency_hz

    def sample(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q, dq, ddq at times ``t`` (s), each (len(t), nj)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        Sq, Sdq, Sddq = _basis(t, self.w, self.a.shape[1])
        c = np.hstack([self.a, self.b]).T  # (2L, nj)
        return Sq @ c + self.q0, Sdq @ c, Sddq @ c

    def times(self, rate: float = DEFAULT_RATE) -> np.ndarray:
        """Sample times 0, 1/rate, ..., duration (s)."""
        return np.arange(int(round(self.duration * rate)) + 1) / rate

    def to_dict(self) -> dict:
        return {"frequency_hz": self.frequency_hz, "a": self.a.tolist(), "b": self.b.tolist(),
                "q0": self.q0.tolist(), "duration": self.duration}

    @classmethod
    def from_dict(cls, d: dict) -> "FourierTrajectory":
        return cls(float(d["frequency_hz"]), np.asarray(d["a"], float), np.asarray(d["b"], float),
                   np.asarray(d["q0"], float), float(d["duration"]))


def _basis(t, w, L):
    """Maps from c = [a_1..a_L, b_1..b_L] to q - q0, dq, ddq at times t: (len(t), 2L) each."""
    wl = w * np.arange(1, L + 1)
    s, c = np.sin(np.outer(t, wl)), np.cos(np.outer(t, wl))
    Sq = np.hstack([s / wl, -c / wl])
    Sdq = np.hstack([c, s])
    Sddq = np.hstack([-s * wl, c * wl])
    return Sq, Sdq, Sddq


def rest_basis(frequency_hz: float, duration: float, harmonics: int = DEFAULT_HARMONICS) -> np.ndarray:
    """Z (2L, m): coefficient vectors c = Z z give dq = ddq = 0 at t = 0 and t = duration and
    q(duration) = q(0). Orthonormal columns."""
    w = 2.0 * np.pi * frequency_hz
    Sq, Sdq, Sddq = _basis(np.array([0.0, duration]), w, harmonics)
    C = np.vstack([Sdq, Sddq, Sq[1] - Sq[0]])
    Z = scipy.linalg.null_space(C, rcond=1e-10)
    if Z.shape[1] == 0:
        raise ValueError(f"{harmonics} harmonics leave no freedom once the trajectory must start "
                         "and end at rest: use more harmonics")
    return Z


@dataclass
class ExcitationResult:
    """The optimised trajectory and its figures (Table 5.1's "optimisation condition number")."""

    trajectory: FourierTrajectory
    condition_objective: float
    condition_full: float
    n_objective_samples: int
    n_full_samples: int
    starts: list = field(default_factory=list)
    scale_applied: float = 1.0
    limit_use: dict = field(default_factory=dict)
    seconds: float = 0.0


class ExcitationDesigner:
    """Optimise eq. 5.28's coefficients to minimise the base regressor's condition number.

    Parameters
    ----------
    regressor_batch : callable
        ``(Q, DQ, DDQ) -> (N * nj, P)`` stacked sample-major.
    base_columns : (r,) int
        Columns of the standard regressor forming the base regressor (``BaseParameters.independent``).
    q_min, q_max, dq_max : (nj,)
        Position limits (rad or m) and velocity limits (rad/s or m/s), Table 4.2.
    ddq_max : (nj,), optional
        Acceleration limits.
    """

    def __init__(self, regressor_batch: Callable, base_columns, q_min, q_max, dq_max, ddq_max=None,
                 frequency_hz: float = DEFAULT_FREQUENCY_HZ, harmonics: int = DEFAULT_HARMONICS,
                 duration: float = DEFAULT_DURATION, rate: float = DEFAULT_RATE,
                 n_objective: int = 400, n_constraint: int = 1500, margin: float = 0.02):
        self.regressor_batch = regressor_batch
        self.cols = np.asarray(base_columns, dtype=int)
        self.q_min, self.q_max, self.dq_max = (np.asarray(x, dtype=float) for x in (q_min, q_max, dq_max))
        self.ddq_max = None if ddq_max is None else np.asarray(ddq_max, dtype=float)
        if np.any(self.q_max <= self.q_min) or np.any(self.dq_max <= 0):
            raise ValueError("limits must satisfy q_min < q_max and dq_max > 0")
        self.nj = self.q_min.shape[0]
        self.f, self.L, self.T, self.rate = float(frequency_hz), int(harmonics), float(duration), float(rate)
        self.margin = float(margin)
        self.Z = rest_basis(self.f, self.T, self.L)
        self.nz = self.Z.shape[1]
        w = 2.0 * np.pi * self.f
        n_full = int(round(self.T * self.rate)) + 1
        self.t_full = np.arange(n_full) / self.rate
        self.t_obj = np.linspace(0.0, self.T, min(n_objective, n_full))
        self.t_con = np.linspace(0.0, self.T, min(n_constraint, n_full))
        self.B_obj = [S @ self.Z for S in _basis(self.t_obj, w, self.L)]
        self.B_con = [S @ self.Z for S in _basis(self.t_con, w, self.L)]
        self._build_linear_constraints()

    # x = [z_1 (nz), ..., z_nj (nz), q0 (nj)]
    def _unpack(self, x):
        z = x[:self.nj * self.nz].reshape(self.nj, self.nz)
        return z, x[self.nj * self.nz:]

    def _trajectory(self, x) -> FourierTrajectory:
        z, q0 = self._unpack(x)
        c = z @ self.Z.T  # (nj, 2L)
        return FourierTrajectory(self.f, c[:, :self.L].copy(), c[:, self.L:].copy(), q0.copy(), self.T)

    def _build_linear_constraints(self):
        """A x + b >= 0 for all limits on the constraint grid."""
        nj, nz, m = self.nj, self.nz, self.t_con.size
        nx = nj * nz + nj
        rows, rhs = [], []
        Bq, Bdq, Bddq = self.B_con
        shrink = 1.0 - self.margin
        span = self.q_max - self.q_min
        for j in range(nj):
            def block(B, with_q0):
                A = np.zeros((m, nx))
                A[:, j * nz:(j + 1) * nz] = B
                if with_q0:
                    A[:, nj * nz + j] = 1.0
                return A
            Aq = block(Bq, True)
            lo, hi = self.q_min[j] + 0.5 * self.margin * span[j], self.q_max[j] - 0.5 * self.margin * span[j]
            rows += [Aq, -Aq]
            rhs += [np.full(m, -lo), np.full(m, hi)]
            Adq = block(Bdq, False)
            rows += [Adq, -Adq]
            rhs += [np.full(m, shrink * self.dq_max[j])] * 2
            if self.ddq_max is not None:
                Addq = block(Bddq, False)
                rows += [Addq, -Addq]
                rhs += [np.full(m, shrink * self.ddq_max[j])] * 2
        self.A_con = np.vstack(rows)
        self.b_con = np.concatenate(rhs)

    def condition(self, traj: FourierTrajectory, t: np.ndarray) -> float:
        """cond of the column-normalised base regressor of ``traj`` sampled at ``t``."""
        Q, DQ, DDQ = traj.sample(t)
        Wb = self.regressor_batch(Q, DQ, DDQ)[:, self.cols]
        n = np.linalg.norm(Wb, axis=0)
        if np.any(n == 0):
            return float("inf")
        s = np.linalg.svd(Wb / n, compute_uv=False)
        return float(s[0] / s[-1]) if s[-1] > 0 else float("inf")

    def _objective(self, x) -> float:
        z, q0 = self._unpack(x)
        Bq, Bdq, Bddq = self.B_obj
        Q, DQ, DDQ = Bq @ z.T + q0, Bdq @ z.T, Bddq @ z.T
        Wb = self.regressor_batch(Q, DQ, DDQ)[:, self.cols]
        n = np.linalg.norm(Wb, axis=0)
        if np.any(n == 0):
            return 1e3
        s = np.linalg.svd(Wb / n, compute_uv=False)
        return float(np.log(s[0] / max(s[-1], 1e-300)))

    def _feasible_start(self, rng, fill: float = 0.6) -> np.ndarray:
        """Random z, scaled so the trajectory uses ``fill`` of the tightest limit; q0 mid-range."""
        z = rng.normal(size=(self.nj, self.nz))
        mid = 0.5 * (self.q_min + self.q_max)
        half = 0.5 * (self.q_max - self.q_min)
        Bq, Bdq, Bddq = self.B_con
        for j in range(self.nj):
            qj, dqj = Bq @ z[j], Bdq @ z[j]
            qdev = np.abs(qj - qj.mean()).max()
            ratios = [qdev / half[j], np.abs(dqj).max() / self.dq_max[j]]
            if self.ddq_max is not None:
                ratios.append(np.abs(Bddq @ z[j]).max() / self.ddq_max[j])
            z[j] *= fill / max(ratios)
            mid[j] -= (Bq @ z[j]).mean()
        return np.concatenate([z.ravel(), mid])

    def _fit_full(self, traj: FourierTrajectory):
        """Scale the motion about the mean position until every full-rate sample is in limits."""
        Q, DQ, DDQ = traj.sample(self.t_full)
        # Scale about the mean position, or the nearest point of the range if the mean is
        # outside it (only then can some scale bring every sample inside).
        qc = np.clip(Q.mean(axis=0), self.q_min, self.q_max)
        scale = 1.0
        for j in range(self.nj):
            dev = Q[:, j] - qc[j]
            up, dn = dev.max(), dev.min()
            if up > 0:
                scale = min(scale, (self.q_max[j] - qc[j]) / up)
            if dn < 0:
                scale = min(scale, (self.q_min[j] - qc[j]) / dn)
            scale = min(scale, self.dq_max[j] / max(np.abs(DQ[:, j]).max(), 1e-300))
            if self.ddq_max is not None:
                scale = min(scale, self.ddq_max[j] / max(np.abs(DDQ[:, j]).max(), 1e-300))
        if scale < 1.0:
            # Shrink slightly below the bound so rounding cannot put a sample outside.
            scale *= 1.0 - 1e-9
            # q = qc + s (q_series + q0 - qc): the series' coefficients scale, q0 moves toward qc.
            traj = FourierTrajectory(traj.frequency_hz, traj.a * scale, traj.b * scale,
                                     qc + scale * (traj.q0 - qc), traj.duration)
        return traj, min(scale, 1.0)

    def limit_use(self, traj: FourierTrajectory) -> dict:
        """Largest fraction of each limit used, per joint, over every full-rate sample (<= 1 is within)."""
        Q, DQ, DDQ = traj.sample(self.t_full)
        half = 0.5 * (self.q_max - self.q_min)
        mid = 0.5 * (self.q_max + self.q_min)
        out = {"q": (np.abs(Q - mid).max(axis=0) / half).tolist(),
               "dq": (np.abs(DQ).max(axis=0) / self.dq_max).tolist()}
        if self.ddq_max is not None:
            out["ddq"] = (np.abs(DDQ).max(axis=0) / self.ddq_max).tolist()
        return out

    def starting_points(self, n_starts: int, seed: int) -> list[np.ndarray]:
        """The seeded starts of `optimise`, in order (the same whether run in turn or at once)."""
        rng = np.random.default_rng(seed)
        return [self._feasible_start(rng) for _ in range(n_starts)]

    def run_start(self, x0: np.ndarray, maxiter: int) -> dict:
        """One SLSQP descent from ``x0``, brought within the limits at every full-rate sample."""
        cons = [{"type": "ineq", "fun": lambda x: self.A_con @ x + self.b_con, "jac": lambda x: self.A_con}]
        f0 = self._objective(x0)
        res = scipy.optimize.minimize(self._objective, x0, method="SLSQP", constraints=cons,
                                      options={"maxiter": maxiter, "ftol": 1e-6, "eps": 1e-6})
        # SLSQP may stop (iteration cap) at a slightly infeasible point: bring it inside
        # the limits at every full-rate sample before comparing starts.
        traj, scale = self._fit_full(self._trajectory(res.x))
        return {"trajectory": traj.to_dict(), "scale": float(scale), "seed_condition": float(np.exp(f0)),
                "condition": float(self.condition(traj, self.t_obj)), "iterations": int(res.nit),
                "message": str(res.message)}

    def optimise(self, n_starts: int = 4, seed: int = 0, maxiter: int = 60,
                 time_budget: float = 100.0, progress: Callable | None = None,
                 run_starts: Callable | None = None) -> ExcitationResult:
        """Minimise the condition number from ``n_starts`` seeded starts within ``time_budget`` s.

        ``progress(start_index, n_starts, best_condition)`` is called after each start.
        ``run_starts(points, maxiter)``, if given, runs the starts itself (e.g. in worker
        processes) and yields ``(k, run_start's dict)`` as each ends; the time budget is
        then the caller's. The result does not depend on which runs them.
        """
        t0 = time.perf_counter()
        points = self.starting_points(n_starts, seed)
        if run_starts is None:
            def run_starts(pts, it):
                for k, x0 in enumerate(pts):
                    if k > 0 and time.perf_counter() - t0 > time_budget * (k / (k + 1)):
                        break  # not enough time left for another start of similar length
                    yield k, self.run_start(x0, it)
        done = {}
        best = np.inf
        for k, out in run_starts(points, maxiter):
            done[k] = out
            best = min(best, out["condition"])
            if progress is not None:
                progress(len(done), n_starts, float(best))
        starts, best_k = [], None
        for k in sorted(done):
            o = done[k]
            starts.append({"start": k, "seed_condition": o["seed_condition"], "condition": o["condition"],
                           "iterations": o["iterations"], "scale": o["scale"], "message": o["message"]})
            if best_k is None or o["condition"] < done[best_k]["condition"]:
                best_k = k
        traj = FourierTrajectory.from_dict(done[best_k]["trajectory"])
        return ExcitationResult(traj, done[best_k]["condition"], self.condition(traj, self.t_full),
                                self.t_obj.size, self.t_full.size, starts, done[best_k]["scale"],
                                self.limit_use(traj), time.perf_counter() - t0)

"""The object's tension from the arms' own joints and efforts, no load cell (issue 47).

Each arm holding the object has a tip force estimate (`calibration.tip_force`, the momentum
observer on its identified model). An element between arms a and b pulls a's tip toward b
with its tension T and b's toward a; with the tips from the measured joints (the project's
kinematics and the registration's RCM frames), every arm's estimated force is the sum of
its elements' pulls:

    F_a = sum over the elements e holding a of T_e w_(e, a),   w_(e, a) = (x_other - x_a) / |...|

Stacked over the arms (three equations per arm) this is solved for the tensions by least
squares, each arm weighted by the inverse of its force covariance from the model's held-out
error on moving joints, or equally in force for a model without held-out figures (on the
simulated rig's cooperative runs weights from the effort noise alone, which trust joint 3
tenfold, gave 0.74 N instead of 0.58 N at worst on the string). Weights that followed
which joints stick jumped at every deadband crossing: the tension's spread carries the
static friction band of every stuck joint, its weights do not. With two arms
and one element the tension is the weighted mean of both arms' pulls along the object.

The estimate is "ambiguous" on a tick where the tension cannot be told from the model's
error: an element's spread beyond ``ambiguous_spread`` (N; the spread carries the static
band of every stuck joint, through how much that joint's torque says of this tension), or
an arm's flags saying its force is unusable in any direction (a joint at a limit, a
singular Jacobian). An arm's joint 3 standing still (its tip-force flag) does not make a
tension ambiguous by itself: in a sideways move joint 3 carries little of it. Where the
torques cannot tell the tension, the object's own stretch carries it
(`calibration.stretch_filter`, given the object's stiffness): the tension the loop is
handed; the torques' own is `torque_tension`, with its `spread` (bench_tension_estimate
has the figures of both).

`TensionSource` is what the cooperative loop is handed: ``update(t, js)`` per tick with the
arms' newest joint states, the element tensions back. `tension_figures` compares the
estimate with a load cell's record while the object moves.

Units: SI (m, N, s).
"""

from __future__ import annotations

import numpy as np

from rig.model import psm_kinematics as K


#: Spread (N) beyond which an element's tension is ambiguous: half the thesis' 0.5 N hold
#: tolerance, so that two spreads still fit in it.
AMBIGUOUS_SPREAD = 0.25


class TensionSource:
    """Tension per object element from the arms' tip force estimates.

    ``estimators``: arm name -> `calibration.tip_force.TipForceEstimator` (forces in frame 0;
    turned into the world here). ``rcm_frames``: arm -> 4 x 4 RCM frame in the world (the
    registration's). ``elements``: the object's elements as pairs of arm names (the load
    cells' order)."""

    def __init__(self, estimators: dict, rcm_frames: dict, elements, ambiguous_spread: float = AMBIGUOUS_SPREAD,
                 stretch=None):
        self.estimators = dict(estimators)
        # the object's own stretch across the ticks the torques cannot tell
        # (calibration.stretch_filter.StretchFilter), or None: the torques alone
        self.stretch = stretch
        self.ambiguous_spread = float(ambiguous_spread)
        self.elements = [tuple(e) for e in elements]
        self.arms = [a for a in self.estimators]
        for a, b in self.elements:
            if a not in self.estimators or b not in self.estimators:
                raise ValueError(f"element {a}-{b}: both arms need a force estimate (have {self.arms})")
        self.R = {a: np.asarray(rcm_frames[a], float)[:3, :3] for a in self.arms}
        self.p = {a: np.asarray(rcm_frames[a], float)[:3, 3] for a in self.arms}
        # frame 0 -> world: the RCM frame in the world is base @ RCM_FRAME
        self.R0 = {a: self.R[a] @ K.RCM_FRAME[:3, :3].T for a in self.arms}
        self._stamp: dict[str, float] = {}
        self._sample: dict = {}
        self.tension = np.zeros(len(self.elements))
        self.torque_tension = np.zeros(len(self.elements))   # the torques' alone (N)
        self.spread = np.full(len(self.elements), np.nan)      # the torques' spread (N)
        self._t_newest: float | None = None
        self.ambiguous = False
        self.why = ""
        self.flags: dict[str, dict] = {}

    def tip_world(self, arm: str, q: np.ndarray) -> np.ndarray:
        return self.p[arm] + self.R[arm] @ K.tip_in_rcm(np.asarray(q, float)[:3])

    def reset(self) -> None:
        for e in self.estimators.values():
            e.reset()
        self._stamp.clear()
        self._sample.clear()
        self._t_newest = None
        if self.stretch is not None:
            self.stretch.reset()

    def update(self, js: dict, default_dt: float) -> np.ndarray:
        """Advance each arm's observer by its joint states and return the tension per
        element (N). ``js[arm]``: its newest joint state, or every one since the last call,
        oldest first (the observer integrates efforts: fed one sample in five of an arm
        whose own impedance varies its effort within each of the loop's periods, it reads
        that variation at one phase, a bias of 0.4-0.9 N over the wire). Each has
        ``position``, ``velocity``, ``effort`` and its stamp ``t``; a sample seen already is
        not fed twice; without stamps every sample is ``default_dt`` s after the last."""
        for a in self.arms:
            for s in (js[a] if isinstance(js[a], (list, tuple)) else [js[a]]):
                self._feed(a, s, default_dt)
        tips = {a: self.tip_world(a, self._sample[a][0]) for a in self.arms}
        return self._solve(tips, default_dt)

    def _feed(self, a: str, s, default_dt: float) -> None:
        stamp = getattr(s, "t", None)
        last = self._stamp.get(a)
        if stamp is not None and last is not None and stamp <= last:
            return
        dt = default_dt if stamp is None or last is None else float(stamp) - last
        self._sample[a] = (np.asarray(s.position, float)[:3],
                           self.estimators[a].update(s.position, s.velocity, s.effort, dt))
        self._stamp[a] = float(stamp) if stamp is not None else (last or 0.0) + default_dt

    def _solve(self, tips: dict, default_dt: float) -> np.ndarray:
        """The tensions from every arm's newest force estimate (least squares), carried by
        the stretch filter where there is one."""
        rows, rhs, weights, covs = [], [], [], []
        for a in self.arms:
            A = np.zeros((3, len(self.elements)))
            for k, (x, y) in enumerate(self.elements):
                if a in (x, y):
                    other = y if a == x else x
                    d = tips[other] - tips[a]
                    A[:, k] = d / max(np.linalg.norm(d), 1e-9)
            sample = self._sample[a][1]
            R0 = self.R0[a]
            rows.append(A)
            rhs.append(R0 @ sample.force)
            weights.append(np.eye(3) if sample.base_covariance is None
                           else np.linalg.inv(R0 @ sample.base_covariance @ R0.T))
            covs.append(R0 @ sample.covariance @ R0.T)
        A = np.vstack(rows)
        b = np.concatenate(rhs)
        W, S = np.zeros((len(b), len(b))), np.zeros((len(b), len(b)))
        for i, (w, c) in enumerate(zip(weights, covs)):
            W[3 * i:3 * i + 3, 3 * i:3 * i + 3] = w
            S[3 * i:3 * i + 3, 3 * i:3 * i + 3] = c
        G = np.linalg.solve(A.T @ W @ A, A.T @ W)       # tensions = G b
        self.torque_tension = G @ b
        # the spread of the weighted mean, stuck joints' static bands included
        self.spread = np.sqrt(np.clip(np.diag(G @ S @ G.T), 0.0, None))
        self.flags = {a: dict(self._sample[a][1].flags) for a in self.arms}
        self.why = self._ambiguity()
        self.ambiguous = bool(self.why)
        newest = max(self._stamp.values())
        dt = default_dt if self._t_newest is None or newest <= self._t_newest else newest - self._t_newest
        self._t_newest = newest
        if self.stretch is None:
            self.tension = self.torque_tension.copy()
        else:
            lengths = [np.linalg.norm(tips[x] - tips[y]) for x, y in self.elements]
            self.tension = self.stretch.update(np.array(lengths), self.torque_tension, self.spread, dt)
        return self.tension.copy()

    def _ambiguity(self) -> str:
        """Why this tick's tension cannot be told from the model's error ("" when it can)."""
        unusable = [f"{a} {f.replace('_', ' ')}" for a in self.arms for f in ("at_limit", "singular")
                    if self.flags[a].get(f)]
        if unusable:
            return ", ".join(unusable)
        wide = [k for k, s in enumerate(self.spread) if s > self.ambiguous_spread]
        if wide:
            return (f"element {', '.join(map(str, wide))} spread {max(self.spread[wide]):.2f} N > "
                    f"{self.ambiguous_spread:g} N (stuck joints' static friction)")
        return ""


def tension_source(dynamics, effects, stick, rcm_frames: dict, arms, elements, gain=None, sigma=None,
                   ambiguous_spread: float = AMBIGUOUS_SPREAD, stiffness: float | None = None,
                   pulls_only: bool = False) -> TensionSource:
    """A `TensionSource` over ``arms``, each on its own model: ``dynamics``, the model file's
    ``effects`` and joint 3's ``stick`` terms are dicts by arm (a single value is every
    arm's); ``sigma`` the held-out spread or None. ``stiffness`` (N/m, the object's; None:
    the torques alone) carries the tension by the object's stretch where the torques cannot
    tell it (`calibration.stretch_filter`); ``pulls_only`` for a string."""
    from calibration.stretch_filter import StretchFilter
    from calibration.tip_force import TipForceEstimator

    def of(x, a):
        return x[a] if isinstance(x, dict) else x

    return TensionSource({a: TipForceEstimator(of(dynamics, a), list(of(effects, a) or []), gain, sigma,
                                               of(stick, a)) for a in arms}, rcm_frames, elements,
                         ambiguous_spread,
                         None if stiffness is None else StretchFilter(
                             len(elements), stiffness, pulls_only,
                             # the torques show the tension through the observers' lag
                             lag_rate=None if gain is None else float(np.min(gain))))


def tension_figures(t: np.ndarray, estimate: np.ndarray, cell: np.ndarray, start: float, end: float) -> dict | None:
    """The estimate against the load cell on the ticks in [start, end] s (the motion): per
    element and over all, the RMS and largest |estimate - cell| and the mean difference
    (bias), N. None without a tick in the window."""
    t, estimate, cell = np.asarray(t, float), np.atleast_2d(estimate), np.atleast_2d(cell)
    during = (t >= start) & (t <= end)
    if not during.any():
        return None
    d = estimate[during] - cell[during]
    return {"rms_difference": float(np.sqrt(np.mean(d ** 2))), "max_difference": float(np.max(np.abs(d))),
            "bias": float(np.mean(d)), "element_rms_difference": np.sqrt(np.mean(d ** 2, axis=0)).tolist(),
            "element_bias": np.mean(d, axis=0).tolist(), "window_s": [float(start), float(end)],
            "ticks": int(during.sum())}

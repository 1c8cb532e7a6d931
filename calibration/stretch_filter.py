"""The object's tension carried by its own stretch where the arms' friction hides it (issue 47).

The arms' torques say the tension (`calibration.tension_estimate`) well while their joints
slide, and only within the static friction band once a joint sticks: the friction that
holds a stuck joint is anywhere in its band, and the model cannot know where. The object
itself says how its tension changes: an elastic element of stiffness k and rest length L0
between two tips pulls with T = k (L - L0) (a string: k max(L - L0, 0)), and its length L
comes from the measured joints. So per element an extended Kalman filter on x = (L0, k),
both slowly wandering (random walks), measured through the torque estimate z:

    z = k * lag(L - L0) + e      lag: the momentum observer's first-order lag of rate
                                 ``lag_rate`` (1/s, its gain): the torques show the tension
                                 late, and a stiff string's pull changes faster than that
    e ~ s^2 c / dt               s: the torque estimate's spread this tick (stuck joints'
                                 bands included, N); c: how long its error keeps its sign:
                                 a stuck joint's friction is one bias for as long as it
                                 sticks, not a fresh error every tick, so the samples
                                 within c count as one

The configured stiffness is the prior of k, within ``stiffness_error`` (relative); the
filter refines it wherever the torques see the stretch change, so a stiffness a lab
measured 20 % off costs seconds of torque-led estimate, not a lasting bias.

With the arms sliding (s a few hundredths of a newton on the simulated rig) the estimate
follows the torques within about a second; with every joint stuck (s about 0.5 N) it leans
on the stretch for many seconds: nothing moves, so the tension cannot change, and a
creeping tip changes it by k dL. Where the prediction itself is unsure (a large stretch
with an uncertain k: the set-point's ramp), the torques lead again.

Where the rest length comes from. A spring's is taken from the torques alone until the
observer has settled (5 / lag_rate s after the start: it starts at rest, whatever the
object pulls). A string pulls only: slack (its length at or below its rest length, or
never yet seen taut) it says nothing of its tension beyond "none", and it is taken as
taut again only when the torques say so beyond doubt (above `contact` by two spreads).
By then the lagging torques are behind a stiff string's sudden pull, so its rest length
is the one whose stretch over the last 5 / lag_rate s, through the observer's lag, gives
the torques' value now (a millimetre of a 20 kN/m string taken wrongly for stretch or
slack is 20 N).

Units: SI (N, m, s).
"""

from __future__ import annotations

import numpy as np

#: N^2/s: how fast the rest length wanders, as tension (the holders slipping, the
#: kinematics' slow errors). With the spread of a sliding arm on the nominal model (0.03 N)
#: the filter follows the torques in s sqrt(c / q) = 1 s; with stuck joints (0.5 N) in 16 s.
Q_RATE = 0.001
#: 1/sqrt(s): how fast the stiffness wanders, relative (a string warming, a spring's
#: hysteresis).
Q_STIFFNESS = 0.01
#: s: how long the torque estimate's error keeps its sign (the bias of a stuck joint's
#: friction, the model's error along a stroke): the samples within it are one measurement.
CORRELATION = 1.0
#: The configured stiffness's relative error: a lab's measured spring within 20 %.
STIFFNESS_ERROR = 0.2
#: N: a string's torque estimate must clear this by two spreads to call it taut.
CONTACT = 0.3
#: Observer time constants the rest length is found over (and a spring's first wait).
SETTLE = 5.0


class StretchFilter:
    """Per element: the tension from the element's stretch, its rest length and stiffness
    corrected by the torque estimate weighted by its spread. ``stiffness`` N/m (one value or
    per element: the prior), ``pulls_only`` for a string. ``rest`` (m) and ``k`` (N/m) per
    element are what it follows (rest NaN for a string never seen taut)."""

    def __init__(self, elements: int, stiffness, pulls_only: bool = False, q_rate: float = Q_RATE,
                 contact: float = CONTACT, stiffness_error: float = STIFFNESS_ERROR,
                 correlation: float = CORRELATION, lag_rate: float | None = None,
                 q_stiffness: float = Q_STIFFNESS):
        from calibration.momentum_observer import DEFAULT_GAIN

        self.lag_rate = float(DEFAULT_GAIN if lag_rate is None else lag_rate)
        self.k0 = np.broadcast_to(np.asarray(stiffness, float), (elements,)).copy()
        if np.any(~(self.k0 > 0)):
            raise ValueError(f"object stiffness must be > 0 N/m, got {stiffness}")
        self.pulls_only = bool(pulls_only)
        self.q_rate = float(q_rate)
        self.q_stiffness = float(q_stiffness)
        self.contact = float(contact)
        self.stiffness_error = float(stiffness_error)
        self.correlation = float(correlation)
        self.elements = int(elements)
        self.reset()

    def reset(self) -> None:
        n = self.elements
        self.tension: np.ndarray | None = None
        self.k = self.k0.copy()
        self.rest = np.full(n, np.nan)
        # covariance of (rest, k) per element
        self.P = np.zeros((n, 2, 2))
        self.P[:, 1, 1] = (self.stiffness_error * self.k0) ** 2
        self.shown_stretch = np.zeros(n)   # lag(L - L0), m: what the observer shows of the stretch
        self.shown_taut = np.zeros(n)      # lag(1 while taut): how much of a rest change it shows
        self.age = 0.0                     # s since the start
        self._history: list[tuple[float, np.ndarray]] = []   # (dt, lengths) over SETTLE / lag_rate
        self._span = 0.0                   # s: the dt's in the history

    def update(self, lengths: np.ndarray, measured: np.ndarray, spread: np.ndarray, dt: float) -> np.ndarray:
        """One tick: the elements' ``lengths`` (m), the torque estimate ``measured`` (N) and
        its ``spread`` (N), ``dt`` s since the last tick. Returns the tension per element (N)."""
        L, z = np.asarray(lengths, float), np.asarray(measured, float)
        s = np.maximum(np.asarray(spread, float), 1e-6)
        first = self.tension is None
        dt = 0.0 if first else max(float(dt), 0.0)
        self.age += dt
        window = SETTLE / self.lag_rate
        self._history.append((dt, L.copy()))
        self._span += dt
        while len(self._history) > 1 and self._span - self._history[0][0] > window:
            self._span -= self._history.pop(0)[0]
        if first:
            self.tension = np.zeros(self.elements)
        for e in range(self.elements):
            if first or (not self.pulls_only and self.age < window):
                self._from_torques(e, L[e], z[e], s[e])
            else:
                self._step(e, L[e], z[e], s[e], dt)
        return self.tension.copy()

    def _from_torques(self, e: int, L: float, z: float, s: float) -> None:
        """The observer still settling: the torques alone, the rest length following them."""
        taut = not self.pulls_only or z > self.contact + 2.0 * s
        self.tension[e] = z if not self.pulls_only else (max(z, 0.0) if taut else 0.0)
        if (taut and self.tension[e] > 0.0) or not self.pulls_only:
            self.rest[e] = L - self.tension[e] / self.k[e]
            self.P[e, 0, 0] = (s / self.k[e]) ** 2
            self.shown_stretch[e], self.shown_taut[e] = L - self.rest[e], 1.0

    def _step(self, e: int, L: float, z: float, s: float, dt: float) -> None:
        k, rest = self.k[e], self.rest[e]
        stretch = L - rest if np.isfinite(rest) else -np.inf
        taut = stretch > 0.0 or not self.pulls_only
        if self.pulls_only and not taut:
            # slack by its length (or never seen taut): none, unless the torques say taut
            if z > self.contact + 2.0 * s:
                self.rest[e] = self._rest_through_lag(e, z)
                self.P[e, 0, 0] = (s / k) ** 2
                self.P[e, 0, 1] = self.P[e, 1, 0] = 0.0
                self.shown_stretch[e], self.shown_taut[e] = z / k, 1.0
                self.tension[e] = k * max(L - self.rest[e], 0.0)
            else:
                a = 1.0 - np.exp(-self.lag_rate * dt)
                self.shown_stretch[e] += a * (0.0 - self.shown_stretch[e])
                self.shown_taut[e] += a * (0.0 - self.shown_taut[e])
                self.tension[e] = 0.0
            return
        a = 1.0 - np.exp(-self.lag_rate * dt)
        self.shown_stretch[e] += a * (stretch - self.shown_stretch[e])
        self.shown_taut[e] += a * (1.0 - self.shown_taut[e])
        P = self.P[e] + np.diag([self.q_rate * dt / k ** 2, (self.q_stiffness * self.k0[e]) ** 2 * dt])
        H = np.array([-k * self.shown_taut[e], self.shown_stretch[e]])
        innovation = z - k * self.shown_stretch[e]
        S = H @ P @ H + s ** 2 * self.correlation / max(dt, 1e-6)
        K = P @ H / S
        d_rest, d_k = K * innovation
        self.rest[e] = rest + d_rest
        self.k[e] = max(k + d_k, 0.1 * self.k0[e])
        self.P[e] = P - np.outer(K, H @ P)
        # a corrected rest length shifts what the observer shows of the stretch alike
        self.shown_stretch[e] -= d_rest * self.shown_taut[e]
        t = self.k[e] * (L - self.rest[e])
        self.tension[e] = max(t, 0.0) if self.pulls_only else t

    def _lagged(self, e: int, rest: float) -> float:
        """The tension element `e` of this `rest` length would show now through the
        observer's lag, over the lengths of the last window (N)."""
        y = 0.0
        for dt, L in self._history:
            y += (1.0 - np.exp(-self.lag_rate * dt)) * (self.k[e] * max(L[e] - rest, 0.0) - y)
        return y

    def _rest_through_lag(self, e: int, z: float) -> float:
        """The rest length (m) whose stretch over the window, through the observer's lag,
        reads `z` N now: bisection between far below the window's lengths and its longest."""
        lengths = [L[e] for _, L in self._history]
        lo, hi = min(lengths) - z / self.k[e] * 10.0, max(lengths)
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            if self._lagged(e, mid) > z:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi)

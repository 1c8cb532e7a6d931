"""The object's tension carried by its own stretch where the arms' friction hides it (issue 47).

The arms' torques say the tension (`calibration.tension_estimate`) well while their joints
slide, and only within the static friction band once a joint sticks: the friction that
holds a stuck joint is anywhere in its band, and the model cannot know where. The object
itself says how its tension changes: an elastic element of stiffness k and rest length L0
between two tips pulls with k (L - L0), and its length L comes from the measured joints.
So per element a scalar Kalman filter on the tension, its rest length following from it:

    predict   T- = k (L - L0)          (a string: k max(L - L0, 0); L0 = L - T/k of the
                                        last tick)
              P- = P + q dt + (e (T- - T))^2
                                       (q, N^2/s: what the stretch model misses over time:
                                        the object's damping and mass, the holders, the
                                        kinematics; e: the configured stiffness's relative
                                        error, on the tension change it predicts)
    correct   K = P- / (P- + s^2 c / dt)
              T = T- + K (z - T-)      (z, s: the torque estimate and its spread this tick,
              P = (1 - K) P-            stuck joints' bands included, N; c: how long its
                                        error keeps its sign: a stuck joint's friction is
                                        one bias for as long as it sticks, not a fresh error
                                        every tick, so the samples within c count as one)

With the arms sliding (s a few hundredths of a newton on the simulated rig) the estimate
follows the torques within about a second; with every joint stuck (s about 0.5 N) it leans
on the stretch for many seconds: nothing moves, so the tension cannot change, and a
creeping tip changes it by k dL. A large stretch (the set-point's ramp) brings its own
uncertainty and the torques take over again.

Where the rest length comes from. The torque estimate is the momentum observer's: the
true tension through a first-order lag of rate ``lag_rate`` (1/s, the observer's gain).
A spring's rest length is taken from the torques alone until the observer has settled
(5 / lag_rate s after the start: it starts at rest, whatever the object pulls). A string
pulls only: slack (its length at or below its rest length, or never yet seen taut) it
says nothing of its tension beyond "none", and it is taken as taut again only when the
torques say so beyond doubt (above `contact` by two spreads). By then the lagging torques
are behind a stiff string's sudden pull, so its rest length is the one whose stretch over
the last 5 / lag_rate s, through the observer's lag, gives the torques' value now (a
millimetre of a 20 kN/m string taken wrongly for stretch or slack is 20 N).

Units: SI (N, m, s).
"""

from __future__ import annotations

import numpy as np

#: N^2/s: the stretch model's drift per second. With the spread of a sliding arm on the
#: nominal model (0.03 N) the filter follows the torques in s sqrt(c / q) = 1 s; with stuck
#: joints (0.5 N) in 16 s.
Q_RATE = 0.001
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
    """Per element: the tension predicted from the element's stretch, corrected by the
    torque estimate weighted by its spread. ``stiffness`` N/m (one value or per element),
    ``pulls_only`` for a string. ``rest`` (m per element) is the rest length it follows
    (NaN for a string never seen taut)."""

    def __init__(self, elements: int, stiffness, pulls_only: bool = False, q_rate: float = Q_RATE,
                 contact: float = CONTACT, stiffness_error: float = STIFFNESS_ERROR,
                 correlation: float = CORRELATION, lag_rate: float | None = None):
        from calibration.momentum_observer import DEFAULT_GAIN

        self.lag_rate = float(DEFAULT_GAIN if lag_rate is None else lag_rate)
        self.k = np.broadcast_to(np.asarray(stiffness, float), (elements,)).copy()
        self.pulls_only = bool(pulls_only)
        self.q_rate = float(q_rate)
        self.contact = float(contact)
        self.stiffness_error = float(stiffness_error)
        self.correlation = float(correlation)
        self.elements = int(elements)
        self.reset()

    def reset(self) -> None:
        self.tension: np.ndarray | None = None
        self.variance: np.ndarray | None = None
        self.shown: np.ndarray | None = None    # the tension through the observer's lag (N)
        self.rest = np.full(self.elements, np.nan)
        self.age = 0.0                                   # s since the start
        self._history: list[tuple[float, np.ndarray]] = []   # (dt, lengths) over SETTLE / lag_rate

    def update(self, lengths: np.ndarray, measured: np.ndarray, spread: np.ndarray, dt: float) -> np.ndarray:
        """One tick: the elements' ``lengths`` (m), the torque estimate ``measured`` (N) and
        its ``spread`` (N), ``dt`` s since the last tick. Returns the tension per element (N)."""
        L, z = np.asarray(lengths, float), np.asarray(measured, float)
        s = np.maximum(np.asarray(spread, float), 1e-6)
        r = s ** 2
        first = self.tension is None
        dt = 0.0 if first else max(float(dt), 0.0)
        self.age += dt
        window = SETTLE / self.lag_rate
        self._history.append((dt, L.copy()))
        while sum(h[0] for h in self._history[1:]) > window:
            self._history.pop(0)
        if first or (not self.pulls_only and self.age < window):
            # the observer still settling: the torques alone
            self.tension, self.variance = (np.maximum(z, 0.0) if self.pulls_only else z.copy()), r.copy()
            self.shown = self.tension.copy()
            self._rest_from(L, z > self.contact + 2.0 * s if self.pulls_only else np.ones(len(z), bool))
            return self.tension.copy()
        stretch = self.k * (L - self.rest)
        prior = np.maximum(stretch, 0.0) if self.pulls_only else stretch
        prior = np.where(np.isnan(prior), 0.0, prior)
        # what the observer shows of the predicted tension: its first-order lag
        shown = self.shown + (1.0 - np.exp(-self.lag_rate * dt)) * (prior - self.shown)
        p = self.variance + self.q_rate * dt + (self.stiffness_error * (prior - self.tension)) ** 2
        gain = p / (p + r * self.correlation / max(dt, 1e-6))
        # the innovation is an error of the rest length: it shifts the tension and what
        # the observer shows of it alike
        correction = gain * (z - shown)
        tension, shown, variance = prior + correction, shown + correction, (1.0 - gain) * p
        if self.pulls_only:
            # slack by its length (or never seen taut): none, unless the torques say taut
            slack = ~(stretch > 0.0)
            taut_now = slack & (z > self.contact + 2.0 * s)
            for e in np.flatnonzero(taut_now):
                self.rest[e] = self._rest_through_lag(e, z[e])
            tension = np.where(slack, np.where(taut_now, self.k * np.maximum(L - self.rest, 0.0), 0.0),
                               np.maximum(tension, 0.0))
            shown = np.where(taut_now, z, shown)
            variance = np.where(slack, r, variance)
            self.tension, self.shown, self.variance = tension, shown, variance
            self._rest_from(L, ~slack)
        else:
            self.tension, self.shown, self.variance = tension, shown, variance
            self._rest_from(L, np.ones(len(z), bool))
        return self.tension.copy()

    def _lagged(self, e: int, rest: float) -> float:
        """The tension element `e` of this `rest` length would show now through the
        observer's lag, over the lengths of the last window (N)."""
        y = 0.0
        for dt, L in self._history:
            y += (1.0 - np.exp(-self.lag_rate * dt)) * (self.k[e] * max(L[e] - rest, 0.0) - y)
        return y

    def _rest_through_lag(self, e: int, z: float) -> float:
        """The rest length (m) whose stretch over the window, through the observer's lag,
        reads `z` N now: bisection between the shortest length of the window (the most it
        can pull) and the window's longest (none)."""
        lengths = [L[e] for _, L in self._history]
        lo, hi = min(lengths) - z / self.k[e] * 10.0, max(lengths)
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            if self._lagged(e, mid) > z:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi)

    def _rest_from(self, L: np.ndarray, which: np.ndarray) -> None:
        """The rest length that gives this tick's tension at its length (taut elements)."""
        if self.pulls_only:
            which = which & (self.tension > 0.0)
        self.rest = np.where(which, L - self.tension / self.k, self.rest)

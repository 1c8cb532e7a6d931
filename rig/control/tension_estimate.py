"""The object's tension as the force loop sees it: filtered, with its rate, held while blind.

Each element's newest sample feeds a Kalman differentiator. While the newest sample is too
old to act on (`blind`: the caller judges its age against the load cell's frame period)
the estimate holds: it is not extrapolated over a gap of unknown length, and the loops
built on it hold too. A hold lasts until a new sample arrives (with three cells: from every
one), and the first sample after it restarts the filter (the rate over the gap is
unknown; taken as one step's change it would kick the offsets by the damping gain).
"""

from __future__ import annotations

import numpy as np

from rig.control.controllers import KalmanDifferentiator


class TensionEstimate:
    """`tension` and `tension_rate` (N, N/s per element), `raw_tension` (the newest samples),
    `blind` (the last update held)."""

    def __init__(self, elements: int, dt: float, noise: float):
        self.dt = dt
        self.filter = KalmanDifferentiator(elements, dt, noise, 200.0)
        self.tension = np.zeros(elements)
        self.tension_rate = np.zeros(elements)
        self.raw_tension = np.zeros(elements)
        self.blind = False
        self._t: float | None = None   # the samples' time (s), when the caller gives it

    def start(self, tension: np.ndarray, tension_t: np.ndarray | None) -> None:
        """Start from the samples `tension` taken at `tension_t` (None: untimed)."""
        self.filter.reset(np.asarray(tension, float))
        self._t = None if tension_t is None else float(np.mean(tension_t))
        self.raw_tension = np.asarray(tension, float).copy()
        self.tension = self.raw_tension.copy()
        self.tension_rate = np.zeros(len(self.tension))
        self.blind = False

    def update(self, tension: np.ndarray | None, tension_t: np.ndarray | None, blind: bool,
               dt_tick: float, timed: bool) -> bool:
        """One cycle: `tension` the newest samples (None: none new), `tension_t` their time,
        `dt_tick` s since the last cycle, `timed` whether the caller gives sample times at
        all. Returns whether the estimate holds this cycle."""
        hold = bool(blind) or (self.blind and tension is None)
        if hold:
            pass  # keep the last estimate: no extrapolation over a gap of unknown length
        elif tension is not None:
            self.raw_tension = np.asarray(tension, float).copy()
            if self.blind:
                self.filter.reset(self.raw_tension)
                self.tension, self.tension_rate = self.raw_tension.copy(), np.zeros_like(self.raw_tension)
            else:
                dt_f = None
                if tension_t is not None and self._t is not None:
                    dt_f = max(float(np.mean(tension_t)) - self._t, 0.1 * self.dt)
                self.tension, self.tension_rate = self.filter.update(np.asarray(tension, float), dt=dt_f)
            if tension_t is not None:
                self._t = float(np.mean(tension_t))
        else:
            self.tension, self.tension_rate = self.filter.update(self.filter.x[:, 0], dt=dt_tick if timed else None)
            if self._t is not None:
                self._t += dt_tick
        self.blind = hold
        return hold

"""The arms' filtered joints, and the master's lag behind its plan that the slaves follow.

`JointEstimate` filters each arm's joint samples (quantised position plus the noisy velocity
the dVRK reports). Given the samples' own times it steps each filter by the samples'
intervals (a sample seen again is not fed twice): over the wire a loop asked for 200 Hz
ran at 120-160 Hz, and taken as `dt` apart its filters read rates 25-65 % too fast.

`master_lag`: the master's PID lags its plan and slips out of static friction in steps;
slaves add its lag (position and velocity) to their own plan, so that their impedance does
not resist the motion the object imposes (the damping along the object is hundreds of
N s/m: a lag changing by a millimetre per second is a newton). The lag's acceleration is
left out: differentiated twice, the measurement is noise. The lag is taken at the time of
the master's sample: against the plan of now, a sample `age` s old reads the plan's own
motion over that age as lag, and the slaves would trail the master by v x age (over the
wire samples were 7 ms old at the median and 50-100 ms at the worst: 20 mm/s x 50 ms is
1 mm, 0.7 N on the spring).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from rig.control.controllers import KalmanDifferentiator
from rig.model import psm_kinematics as K


class JointEstimate:
    """Per arm: filtered joints (`update`), and when each sample was taken on this loop's clock."""

    def __init__(self, arms: list[str], dt: float):
        self.arms = list(arms)
        self.filters = {a: KalmanDifferentiator(3, dt, [6e-6, 6e-6, 1e-6], [20.0, 20.0, 5.0],
                                                rate_noise=[2e-3, 2e-3, 3e-4]) for a in self.arms}
        self._filtered: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._stamp: dict[str, float] = {}
        # per arm, the smallest (this loop's time - the sample's stamp) seen: the offset of
        # the stamps' clock (another computer's: the console's) plus the shortest way here
        self._offset: dict[str, float] = {}
        self._intervals_ready = False

    def start(self, t: float, q: dict[str, np.ndarray], dq: dict[str, np.ndarray],
              stamps: dict[str, float] | None) -> bool:
        """Restart every filter; returns whether the samples come with their times (their
        filters' gains for the samples' own intervals are solved here, before the loop)."""
        for a in self.arms:
            self.filters[a].reset(q[a], dq[a])
        self._filtered = {a: (np.asarray(q[a], float).copy(), np.asarray(dq[a], float).copy()) for a in self.arms}
        self._stamp = dict(stamps) if stamps is not None else {}
        self._offset = {a: t - float(stamps[a]) for a in self.arms} if stamps is not None else {}
        ready_now = stamps is not None and not self._intervals_ready
        if ready_now:
            for f in self.filters.values():
                f.prepare_intervals()
            self._intervals_ready = True
        return ready_now

    def update(self, t: float, q: dict[str, np.ndarray], dq: dict[str, np.ndarray],
               stamps: dict[str, float] | None) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
        qf, dqf = {}, {}
        for a in self.arms:
            if stamps is None:
                qf[a], dqf[a] = self.filters[a].update(q[a], dq[a])
                continue
            self._offset[a] = min(self._offset.get(a, np.inf), t - float(stamps[a]))
            last = self._stamp.get(a)
            if last is not None and stamps[a] <= last:
                qf[a], dqf[a] = self._filtered[a]  # the sample the last step had
                continue
            qf[a], dqf[a] = self.filters[a].update(q[a], dq[a], dt=None if last is None else stamps[a] - last)
            self._stamp[a] = float(stamps[a])
            self._filtered[a] = (qf[a], dqf[a])
        return qf, dqf

    def sample_time(self, arm: str, t: float) -> float:
        """When the arm's newest sample was taken, on this loop's clock (at most `t`)."""
        return min(t, self._stamp[arm] + self._offset[arm])


def master_lag(master: str, t: float, timed: bool, joints: JointEstimate, qf: dict, dqf: dict,
               tips: dict[str, np.ndarray], R: np.ndarray, plan_now: tuple[dict, dict],
               plan_at: Callable[[float], tuple[dict, dict, dict]]) -> tuple[np.ndarray, np.ndarray]:
    """(position, velocity) of the master's tip minus its plan at its sample's time (world,
    m and m/s); `plan_now`: the plan's (xd, vd) at `t`, `plan_at(t)` the plan at another
    time; `R`: the master's RCM frame rotation."""
    Jm = K.tip_jacobian_rcm(qf[master])
    t_m = t if not timed else joints.sample_time(master, t)
    xm, vm = plan_now if t_m == t else plan_at(t_m)[:2]
    return tips[master] - xm[master], R @ (Jm @ dqf[master]) - vm[master]

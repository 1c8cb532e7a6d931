"""A slack object is taken up before the tension set-point ramps up to the target.

At the start a slave whose tracked tension is below the contact force is slack. Each
slave strategy takes its slack up its own way (rig.control.slave_strategies); once every
slave holds its object taut, the set-point rises from the tension then held to the target
on a minimum-jerk ramp. An object taut from the start ramps at once.
"""

from __future__ import annotations

import numpy as np

from rig.control.cooperative_plan import min_jerk


class SlackTakeUp:
    """`slack` per slave, `ramp_start` (s, None while any slave is slack), the tension the
    ramp starts from (`initial_tension`, N, mean over the slaves' tracked elements) and each
    element's (`initial_element_tension`)."""

    def __init__(self, slaves: list[str], force: float, ramp_time: float, contact: float,
                 scale_ramp: bool):
        self.slaves = list(slaves)
        self.force = float(force)
        self.ramp_time = ramp_time
        self.contact = contact
        # taken up by force (the arm's impedance), the object starts the ramp part-way up:
        # the rest of it takes its share of the ramp time (at least 0.3 s)
        self.scale_ramp = scale_ramp
        self.slack = {s: False for s in self.slaves}
        self.ramp_start: float | None = None
        self.initial_tension = 0.0
        self.initial_element_tension = np.zeros(0)

    def start(self, t: float, tension: np.ndarray, tracked: dict[str, float], take_up: bool) -> None:
        """From the element `tension` at `t`; `tracked`: each slave's tracked tension;
        `take_up`: whether slack is taken up at all (the impedance mode, a set-point above contact)."""
        self.initial_tension = float(np.mean(tension)) if len(tension) else 0.0
        self.initial_element_tension = np.asarray(tension, float).copy()
        self.slack = {s: take_up and tracked[s] < self.contact for s in self.slaves}
        self.ramp_start = t if not any(self.slack.values()) else None

    @property
    def any_slack(self) -> bool:
        return any(self.slack.values())

    def taut(self, slave: str, t: float, tracked: dict[str, float]) -> None:
        """The slave holds its object taut at `t`; with every slave taut the ramp starts
        from the mean of their `tracked` tensions."""
        self.slack[slave] = False
        if not self.any_slack:
            self.ramp_start = t
            self.initial_tension = float(np.mean([tracked[a] for a in self.slaves]))

    def set_point(self, t: float, offset: float) -> float:
        """The tension set-point (N) at `t`, with the user's applied `offset`."""
        if self.ramp_start is None:      # still taking up slack
            return self.initial_tension + offset
        ramp = self.ramp_time
        if self.scale_ramp and self.force > 0:
            ramp *= max(0.3, min(1.0, (self.force - self.initial_tension) / self.force))
        s = (t - self.ramp_start) / ramp if ramp > 0 else 1.0
        p, _, _ = min_jerk(s)
        return self.initial_tension + p * (self.force - self.initial_tension) + offset

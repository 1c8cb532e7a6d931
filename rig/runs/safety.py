"""Safety limits as data, checked every control cycle.

A breach raises `AbortRun` with one line naming what and by how much; the run engine
(`rig.runs.run.Run`) then holds every arm the run moved and finalises the recording as aborted.
`plan_violation` checks a planned trajectory the same way for `--dry-run`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rig.model import psm_kinematics as K
from rig.runs.run import AbortRun


@dataclass
class SafetyLimits:
    tension_ceiling: float = 15.0                      # N, below the suture break strength
    joints: K.JointLimits = field(default_factory=K.JointLimits)
    effort_limit: np.ndarray = field(default_factory=lambda: np.array([5.0, 5.0, 15.0]))  # N m, N m, N
    workspace_min: np.ndarray = field(default_factory=lambda: np.array([0.2, -0.35, -0.25]))  # m, world
    workspace_max: np.ndarray = field(default_factory=lambda: np.array([0.9, 0.35, 0.15]))    # m, world
    velocity_margin: float = 1.0                       # fraction of Table 4.2 velocities allowed
    # A position-controlled arm's PID may touch the drive limit for a moment; only a
    # measured effort beyond the limit by this factor (a fault, not saturation) aborts.
    measured_effort_factor: float = 1.1

    def check_effort(self, name: str, effort: np.ndarray, measured: bool = False) -> None:
        """A commanded effort above the ceiling, or a measured one well beyond it, aborts."""
        ceiling = self.effort_limit * (self.measured_effort_factor if measured else 1.0)
        over = np.abs(effort) > ceiling
        if over.any():
            j = int(np.argmax(over))
            what = "measured effort" if measured else "commanded effort"
            unit = "N" if j == 2 else "N m"  # joint 3 is the insertion (prismatic)
            raise AbortRun(f"{name}: joint {j + 1} {what} {effort[j]:+.2f} {unit}, beyond its limit "
                           f"+/-{ceiling[j]:.2f} {unit}", arm=name, joint=j + 1, limit=what)

    def check_arm(self, name: str, q: np.ndarray, dq: np.ndarray, effort: np.ndarray | None,
                  tip_world: np.ndarray) -> None:
        problem = self.joints.violation(q, dq / self.velocity_margin if self.velocity_margin else dq)
        if problem:
            raise AbortRun(f"{name}: {problem}", arm=name, limit="joint")
        if effort is not None:
            self.check_effort(name, effort, measured=True)
        out = (tip_world < self.workspace_min) | (tip_world > self.workspace_max)
        if out.any():
            axis = "xyz"[int(np.argmax(out))]
            raise AbortRun(f"{name}: tool tip {axis} = {tip_world['xyz'.index(axis)]:.3f} m outside the "
                           f"workspace box [{self.workspace_min['xyz'.index(axis)]:.3f}, "
                           f"{self.workspace_max['xyz'.index(axis)]:.3f}] m", arm=name, limit="workspace")

    def check_tension(self, tension: float) -> None:
        if tension > self.tension_ceiling:
            raise AbortRun(f"tension {tension:.2f} N above the ceiling {self.tension_ceiling:.2f} N",
                           limit="tension")

    def plan_violation(self, name: str, q_path: np.ndarray, dq_path: np.ndarray,
                       tips_world: np.ndarray) -> str | None:
        """First limit a planned joint path breaks (None when the plan is inside every limit)."""
        for q, dq, tip in zip(q_path, dq_path, tips_world):
            try:
                self.check_arm(name, q, dq, None, tip)
            except AbortRun as exc:
                return exc.reason
        return None

"""What a control law asks of one arm for one cycle: a position, an effort or an impedance goal."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np


class CommandKind(StrEnum):
    """The arm's command a cycle sends: servo_jp, servo_jf or servo_ci."""

    POSITION = "position"
    EFFORT = "effort"
    IMPEDANCE = "impedance"


@dataclass
class ArmCommand:
    kind: CommandKind
    q: np.ndarray | None = None     # servo_jp position (rad, rad, m)
    dq: np.ndarray | None = None    # servo_jp velocity
    effort: np.ndarray | None = None  # servo_jf effort (N m, N m, N)
    # IMPEDANCE (the arm's servo_ci, see rig.control.arm_impedance): the shaft end's target and
    # velocity (RCM frame), the object's direction u there, the spring and damper on the
    # axes of rig.control.arm_impedance.force_frame(u), joint feedforward (N m, N m, N)
    target: np.ndarray | None = None
    velocity: np.ndarray | None = None
    u: np.ndarray | None = None
    stiffness: np.ndarray | None = None
    damping: np.ndarray | None = None
    feedforward: np.ndarray | None = None

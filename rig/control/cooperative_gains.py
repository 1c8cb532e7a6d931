"""The cooperative controller's gains and the choices that name its parts (SI units).

`Mode` and `SlaveControl` say which slave strategy runs (rig.control.slave_strategies);
`preset` and `arm_preset` give the gains per object. The figures the presets were chosen
on are in the docstrings of bench/bench_cooperative.py (the effort path) and
bench/bench_cooperative_arm.py (the impedance in the arm), which measure them again.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np


class Mode(StrEnum):
    """How the slaves track the tension: an impedance with a moving target (7.3, 7.10-7.12),
    or fixed steps of a position target (7.7.3)."""

    IMPEDANCE = "impedance"
    POSITION = "position"


class SlaveControl(StrEnum):
    """Who closes a slave's impedance: this loop, commanding efforts (servo_jf), or the arm
    in its servo loop (the dVRK's servo_ci), this loop moving its goal and feedforward."""

    EFFORT = "effort"
    ARM = "arm"


def choice(enum: type[StrEnum], value, what: str) -> StrEnum:
    """`value` as a member of `enum`, or a ValueError naming the choices."""
    try:
        return enum(value)
    except ValueError:
        names = " or ".join(repr(m.value) for m in enum)
        raise ValueError(f"{what} must be {names}, got {value!r}") from None


@dataclass
class ForceLoop:
    """Gains of the tension loop (eq. 7.12 plus damping); SI units."""

    k_i: float = 0.08          # m/(N s): x_f rate per newton of tension error
    k_damp: float = 0.0015     # m/N: x_f rate per N/s of tension rate (the damping term)
    deadband: float = 0.02     # N: no integration inside it
    ramp_time: float = 1.0     # s: minimum-jerk ramp of the set-point from the initial tension
    # A slack object (tension below `contact` N) is taken up with the slave's tip moving
    # outward at `take_up_speed` (m/s; x_f integrates the speed error with `take_up_gain`,
    # 1/s) before the set-point ramp starts: integrating the tension error over the slack
    # would arrive at the object fast with the target far beyond it (2 N overshoot on a string).
    contact: float = 0.5
    take_up_speed: float = 0.01
    take_up_gain: float = 10.0
    take_up_force: float = 3.0   # N (at most 0.6 of the set-point): the arm takes a slack object up by this force
    x_f_limit: float = 0.03    # m: |x_f| ceiling (the object cannot need more)
    bandwidth_ratio: float = 3.0  # the loop stays this factor below the arm-object mode
    tick_gain: float = 0.1        # and its crossover at most this over one loop period


@dataclass
class ImpedanceGains:
    Md: np.ndarray | None = None   # kg; None: the arm's own Cartesian inertia (see Impedance)
    Kp: np.ndarray = field(default_factory=lambda: np.array([400.0, 400.0, 400.0]))  # N/m, along the object
    # N/m across the object; None: Kp in every direction. A slave soft along the object but
    # stiff across it holds its place against model and gravity errors without stiffening
    # the force loop.
    Kp_across: float | None = None
    Kd: np.ndarray = field(default_factory=lambda: np.array([20.0, 20.0, 20.0]))  # N s/m (with Md)
    damping_ratio: float | None = 0.7   # with Md None: ratio against Kp + the object's stiffness
    # With Md None: proportional tension feedback k_fp (F_d - F) along the object, added to
    # the impedance force. It divides a force disturbance on the slave (friction, model
    # error) by 1 + k_fp below the arm-object mode, which it stiffens by as much (the
    # damping is designed against Kp + (1 + k_fp) K_obj).
    force_feedback: float = 0.0


@dataclass
class ArmImpedanceGains:
    """A slave's impedance run by the arm (the dVRK's servo_ci): a spring `kp_along` (N/m)
    along the object and `kp_across` across it, damped at `damping_ratio` against the
    arm's Cartesian inertia along each axis and the spring plus the object's stiffness."""

    kp_along: float = 400.0
    kp_across: float = 1000.0
    damping_ratio: float = 0.7


@dataclass
class PositionForceLoop:
    """Thesis 7.7.3: both arms in position control; a slave steps its target by `step` (m)
    every `period` (s) while the tension error is outside `deadband` (N).

    The thesis stepped at 500 Hz on the real dVRK. The simulated joint PIDs settle in tens
    of milliseconds, and stepping every 2 ms outruns them (every deadband then limit-cycles
    by several newtons); at 50 Hz the thesis' finding shows: a 0.2 mm step moves the spring's
    tension by about 0.5 N, so a deadband narrower than half a step hunts and a wider one
    settles (bench/bench_cooperative.py's position-mode rows)."""

    step: float = 0.0002
    period: float = 0.02
    deadband: float = 0.4


def preset(kind: str) -> tuple[ImpedanceGains, bool]:
    """Impedance gains and whether slaves follow the master's measured motion, per object.

    A compliant spring (~2.5 kN/m) tolerates feeding the measured force back with a desired
    inertia, which gives the tension loop bandwidth. A string (>= 20 kN/m) does not (the
    sampled, filtered force arrives too late for an arm-object mode above 200 rad/s): there
    the slave keeps its own inertia and gets a moderate proportional tension feedback on the
    raw samples instead (k_fp 10 divides friction and model disturbances by 11). Both
    follow the master's measured motion: the master's PID lags its plan and slips out of
    static friction in steps, which a slave following the plan would pass into the object.
    Chosen on bench/bench_cooperative.py (its docstring keeps what else was tried).
    """
    if kind == "spring":
        return ImpedanceGains(Md=np.full(3, 1.0), Kp=np.full(3, 400.0), damping_ratio=0.7), True
    if kind == "string":
        return ImpedanceGains(Md=None, Kp=np.full(3, 200.0), damping_ratio=0.3, Kp_across=None,
                              force_feedback=10.0), True
    raise ValueError(f"object kind must be 'spring' or 'string', got {kind!r}")


def arm_preset(kind: str) -> ArmImpedanceGains:
    """Gains of a slave whose impedance the arm runs (servo_ci), per object.

    The arm closes the spring and damper in its own servo loop next to the motors, and the
    set-point is fed forward (force and stretch), so the spring along the object only
    has to carry what the feedforward misses: friction at the start and end of a motion,
    model error. The stiffer it is, the less of that reaches the object (K_obj / (Kp +
    K_obj)); the tension loop's gain is capped by the series stiffness, so stiffer is also
    slower to correct. Damped at a ratio of 1 against spring + object; across the object
    1000 N/m holds the slave on its path. Chosen on bench/bench_cooperative_arm.py (its
    docstring keeps what else was tried)."""
    if kind == "spring":
        return ArmImpedanceGains(kp_along=1000.0, damping_ratio=1.0)
    if kind == "string":
        return ArmImpedanceGains(kp_along=2000.0, damping_ratio=1.0)
    raise ValueError(f"object kind must be 'spring' or 'string', got {kind!r}")

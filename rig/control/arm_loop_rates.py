"""The rates the arms must publish at for `rig cooperative` with the slaves' impedance in
the arm (servo_ci): below them it is refused in one line naming the console's `-p`, and
`rig doctor` checks a console against them."""

from __future__ import annotations

#: Hz: the lowest rate of the arms' streams the arm-impedance path runs at, per object
#: ("three": the triangle of three arms); a slower console is refused in one line naming
#: its `-p`. The loop itself runs at most procedures.cooperative's ARM_LOOP_MAX_RATE.
#: Measured on bench/bench_cooperative_arm.py and bench/bench_cooperative_wire.py (their
#: docstrings keep the figures).
ARM_LOOP_MIN_RATE = {"spring": 100.0, "string": 500.0, "three": 500.0}


def arm_loop_min_rate(kind: str, arms: int) -> float:
    """ARM_LOOP_MIN_RATE for an object of `kind` held by `arms` arms."""
    return ARM_LOOP_MIN_RATE["three"] if arms > 2 else ARM_LOOP_MIN_RATE[kind]

"""The rates the arms must publish at for `rig cooperative` with the slaves' impedance in
the arm (servo_ci): below them it is refused in one line naming the console's `-p`, and
`rig doctor` checks a console against them."""

from __future__ import annotations

#: Hz: the lowest rate of the arms' streams the arm-impedance path runs at, per object
#: ("three": the triangle of three arms); a slower console is refused in one line naming
#: its `-p`. The loop itself runs at most ARM_LOOP_MAX_RATE. In sim time
#: (bench_cooperative_arm, loop at 100 Hz) every object holds from 100 Hz streams: the
#: spring and the triangle 0.14-0.16 N, the string 0.27-0.35 N. Against rig sim on this
#: 2-core machine (bench_cooperative_wire, quiet, 3 runs each) at 100 Hz streams the spring
#: held 0.18-0.43 N, but the string aborted 1 of 3 on the tension ceiling (2.6-5.3 N in the
#: others) and the triangle 3 of 3; at 500 Hz streams neither aborted (string 0.85-1.9 N,
#: triangle 0.47-1.8 N): they need the faster console.
ARM_LOOP_MIN_RATE = {"spring": 100.0, "string": 500.0, "three": 500.0}


def arm_loop_min_rate(kind: str, arms: int) -> float:
    """ARM_LOOP_MIN_RATE for an object of `kind` held by `arms` arms."""
    return ARM_LOOP_MIN_RATE["three"] if arms > 2 else ARM_LOOP_MIN_RATE[kind]

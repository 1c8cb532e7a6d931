"""A simulated PSM pulled by a spring of known stiffness: its recording and the true force
on its tip (issue 47's known truth for the force estimate)."""

from __future__ import annotations

import numpy as np

Q0 = np.array([0.0, 0.0, 0.12])


def facing(x: float) -> np.ndarray:
    """Frame 0 of an arm at x (m) on the world's x axis, turned to face the arm at the origin."""
    T = np.eye(4)
    T[0, 3] = x
    T[:2, :2] = [[-1.0, 0.0], [0.0, -1.0]]
    return T


def world(stretch: float | None, seed: int = 1):
    """PSM1 at the origin, PSM2 facing it, a 2450 N/m spring between the tips stretched by
    ``stretch`` m at the start (None: no object)."""
    from rig.sim.world import ArmSpec, ObjectSpec, SimWorld

    w = SimWorld([ArmSpec("PSM1", q0=Q0), ArmSpec("PSM2", base=facing(1.0728), q0=Q0)], None, seed=seed)
    if stretch is not None:
        d0 = float(np.linalg.norm(w.tip_world("PSM2") - w.tip_world("PSM1")))
        w.attach_object(ObjectSpec(("PSM1", "PSM2"), 2450.0, 5.0, d0 - stretch, "spring"))
    return w


def motion(s: float) -> tuple[np.ndarray, np.ndarray]:
    """PSM1's joint path (rad, rad, m and their rates): every joint swinging."""
    amp, f = np.array([0.08, 0.06, 0.02]), np.array([0.4, 0.3, 0.5])
    return Q0 + amp * np.sin(2 * np.pi * f * s), amp * 2 * np.pi * f * np.cos(2 * np.pi * f * s)


def pulled_recording(stretch: float | None, seconds: float, moving_from: float, every: int = 2, seed: int = 1):
    """PSM1 follows `motion` under its PID after ``moving_from`` s, PSM2 holds. Returns
    (rate Hz, q, dq, tau as PSM1 reports them, the true force on PSM1's tip (n, 3) N in the
    world = PSM1's frame 0), one sample every ``every`` world steps."""
    w = world(stretch, seed)
    q, dq, tau, true = [], [], [], []
    for k in range(int(round(seconds / w.dt))):
        t = k * w.dt
        if t >= moving_from:
            w.servo_jp("PSM1", *motion(t - moving_from))
        w.step()
        if k % every:
            continue
        a, b, c = w.measured_js("PSM1")
        q.append(a)
        dq.append(b)
        tau.append(c)
        d = w.tip_world("PSM2") - w.tip_world("PSM1")
        true.append(w.tension(0) * d / np.linalg.norm(d) if w.object is not None else np.zeros(3))
    return 1.0 / (every * w.dt), np.array(q), np.array(dq), np.array(tau), np.array(true)

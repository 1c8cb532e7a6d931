"""The cooperative loop with the slaves' impedance in the arm (servo_ci), over a wire emulated in sim time.

`emulate` runs what `rig cooperative` does over the wire against `rig sim`, with the
wire's timing made exact and repeatable: the simulated world steps at the rig rate with
each arm a whole dVRK PSM (`drivers.arm.fake_psm.FakePSM`, its servo_ci run in its servo loop);
the arms' state and the load cell are "published" every ROS period and reach the
procedure's loop `delay` periods later; the loop's commands (master servo_jp, slaves'
servo_ci built as the crtk_msgs message `RosArm` sends and read back as rig sim's bridge
reads it) act from the next servo period. The procedure's own controller
(`rig.control.cooperative_controller`, slave_control="arm") runs at the published rate; a held process is
emulated by `hold_every`/`hold` (the loop misses its ticks, then acts on the newest
sample). Used by tests/procedures/test_cooperative_arm.py and bench/bench_cooperative_arm.py.
"""

from __future__ import annotations

import numpy as np


def emulate(kind: str = "spring", period: float = 0.01, delay: float = 1.0, force: float = 5.0,
            move=(0.03, 0.0, 0.0), settle: float = 1.5, duration: float = 2.0, hold_after: float = 0.5,
            hold_every: float = 0.0, hold: float = 0.0, seed: int = 0, arms=("PSM1", "PSM2"),
            rate: float = 500.0, tweak=None, config_path=None, loop_rate: float | None = None,
            controller_rate: float | None = None, stamps: bool = True, gap_every: float = 0.0,
            gap: float = 0.0) -> dict:
    """One cooperative run in sim time (see the module docstring); returns its figures.

    `loop_rate`: the loop's own rate (default: the published rate); `controller_rate`: the
    rate the controller is built for (default: the loop's; the procedure builds it for the
    rate it asks of its clock, which a starved process does not keep); `stamps`: the loop
    hands the controller the samples' times, as the procedure does (False: as before it
    did, every step taken as one period after the last); `gap_every`, `gap`: every
    `gap_every` s the arms' state is not published for `gap` s while the load cell streams
    on (rig sim catching up on a loaded machine; the loop meanwhile sees the last state)."""
    from crtk_msgs.msg import CartesianImpedance

    from drivers.arm.dvrk_arm import impedance_message
    from drivers.arm.fake_psm import FakePSM
    from procedures.cooperative import build_controller
    from rig import config
    from rig.control.arm_impedance import servo_ci_goal
    from rig.devices.clock import SimClock
    from rig.sim_server.crtk_bridge import impedance_from_msg
    from rig.model.psm_dynamics import PSMDynamics
    from rig.sim.world import world_from_config

    cfg = config.load(config_path)
    cfg.rig["rate"] = rate
    cfg.rig["pace"] = False
    cfg.object["kind"] = kind
    cfg.object["stiffness"] = 2450.0 if kind == "spring" else 20000.0
    cfg.object["arms"] = list(arms)
    names = list(arms)
    master = names[-1]
    world = world_from_config(cfg, names, seed=seed)
    clock = SimClock(world)
    psms = {n: FakePSM(world, n, clock) for n in names}
    for p in psms.values():
        p.homed = True
    rcm = {n: cfg.base_matrix(n) @ __import__("rig.model.psm_kinematics", fromlist=["RCM_FRAME"]).RCM_FRAME for n in names}
    elements = [(a, b) for i, a in enumerate(names) for b in names[i + 1:]]
    params = {"force": force, "duration": duration, "settle": settle, "hold_after": hold_after, "deadband": 0.4}
    dyn = PSMDynamics(gravity=np.asarray(cfg.rig["gravity"], float))
    every = max(1, int(round(period * rate)))
    # the loop ticks at the published rate, or at its own `loop_rate` (the procedure's
    # ARM_LOOP_MAX_RATE): a 200 Hz loop on a 500 Hz stream finds samples 4 and 6 ms apart
    loop_dt = every / rate if loop_rate is None else 1.0 / loop_rate
    controller = build_controller(cfg, names, master, params, np.asarray(move, float), np.zeros(3), "impedance",
                                  dyn, None, rcm, kind, cfg.object["stiffness"], elements,
                                  loop_dt if controller_rate is None else 1.0 / controller_rate,
                                  slave_control="arm")
    if tweak is not None:
        tweak(controller)
    rng = np.random.default_rng(seed + 1)
    from rig.model.psm_arm_kinematics import PSMKinematics

    kin = PSMKinematics()
    # let the object settle under the PIDs at the start pose
    for n in names:
        q, _, _ = psms[n].measured_js()
        psms[n].servo_jp(q[:6].copy(), np.zeros(6))
    for _ in range(int(0.5 * rate)):
        for p in psms.values():
            p.control(world.t)
        clock.tick()
        for p in psms.values():
            p.step_wrist()

    def sample():
        """(the arms' stamp, their state, the cell's stamp, its tension)"""
        js = {n: psms[n].measured_js() for n in names}
        ten = np.array([world.tension(k) + rng.normal(0.0, 0.02) for k in range(len(elements))])
        return world.t, js, world.t, ten

    t0, js, _, ten = sample()
    published = (t0, js, t0, ten)
    controller.start(t0, {n: js[n][0][:3] for n in names}, {n: js[n][1][:3] for n in names}, ten,
                     stamps={n: t0 for n in names} if stamps else None,
                     tension_t=np.full(len(elements), t0) if stamps else None)
    hold_R = {n: kin.forward(js[n][0][:6])[:3, :3] for n in controller.slaves}
    total = settle + duration + hold_after
    n_ticks = int(round(total * rate))
    delay_steps = int(round(delay * every))
    queue: list[tuple[int, tuple]] = []
    log_t, log_f, log_sp = [], [], []
    next_hold = hold_every if hold_every > 0 else float("inf")
    held_until = -1.0
    next_tick = world.t
    for k in range(n_ticks):
        for p in psms.values():
            p.control(world.t)
        clock.tick()
        for p in psms.values():
            p.step_wrist()
        if k % every == 0:
            fresh = sample()
            if gap_every > 0 and (fresh[0] - t0) % gap_every > gap_every - gap:
                fresh = (published[0], published[1], fresh[2], fresh[3])  # the arms' state unpublished
            published = fresh
            queue.append((k + delay_steps, fresh))
        t_now = world.t
        if t_now >= next_hold:
            held_until = t_now + hold
            next_hold += hold_every
        if t_now < held_until:
            continue
        ready = [s for due, s in queue if due <= k]
        if not ready or t_now < next_tick - 1e-9:
            continue
        next_tick = max(next_tick + loop_dt, t_now) if loop_rate is not None else t_now
        queue = [(due, s) for due, s in queue if due > k]
        t, js, t_ten, ten = ready[-1]
        q = {n: js[n][0][:3] for n in names}
        dq = {n: js[n][1][:3] for n in names}
        # the loop's clock is now; the samples carry the time they were taken
        commands = controller.step(t_now, q, dq, ten, stamps={n: t for n in names} if stamps else None,
                                   tension_t=np.full(len(elements), t_ten) if stamps else None)
        for n in names:
            c = commands[n]
            if c.kind == "position":
                psms[n].servo_jp(np.concatenate([c.q, js[n][0][3:6]]), np.concatenate([c.dq, np.zeros(3)]))
            else:
                g = servo_ci_goal(kin, js[n][0][:6], c.target, c.velocity, c.u, c.stiffness, c.damping,
                                  c.feedforward, orientation=hold_R[n])
                m = impedance_message(CartesianImpedance(), g.position, g.orientation, g.stiffness, g.damping,
                                      g.bias, torque_stiffness=g.torque_stiffness, torque_damping=g.torque_damping, torque_bias=g.torque_bias,
                                      force_orientation=g.force_orientation)
                psms[n].servo_ci(impedance_from_msg(m))
        log_t.append(t_now - t0)
        log_f.append(float(np.mean(ten)))
        log_sp.append(controller.force_setpoint)
    t = np.array(log_t)
    f = np.array(log_f)
    moving = (t >= settle) & (t <= settle + duration)
    after = t >= settle
    return {"max_error_during_motion": float(np.max(np.abs(f[moving] - force))),
            "overshoot": float(max(0.0, np.max(f) - force)),
            "rms_after_settle": float(np.sqrt(np.mean((f[after] - force) ** 2))),
            "final": float(f[-1]), "trace": (t, f, np.array(log_sp))}

"""The step `rig cooperative` gives the run engine's control loop: hold the tension, one tick.

Each tick (rig.runs.control_loop has already ticked the clock, read the arms and drained
the load cells into the recording) `TensionHold.step` judges how old the newest tension
is, takes the live increments, steps the controller, records the set-point and the tips
and logs the figures; the loop then checks the limits and sends the commands.

The force loop acts only on a tension at most two of the cell's frame periods old (at a
tick the newest sample is up to one period old, plus its way to the loop); older, the
controller holds its force loop (rig.control.tension_estimate). Samples can stop reaching
the loop while the port still has them: the driver's reader thread held up on a loaded
machine (100-475 ms seen over the wire with one CPU burner) delivers them in a burst
later, and its stream age does not count that as silence. A tension no newer than the
stale timeout ends the run (`check_stale_tension`).

Every tick also updates the model's tension estimate (issue 47: `calibration.tension_estimate`),
recorded and logged beside the cell. With `--tension-source model` the force loop closes on
it, as fresh as the joint states it came from; a rig without a load cell then runs on it alone.
"""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np

from procedures import cooperative_figures as figures
from procedures.cooperative_estimate import stamps
from rig.control.cooperative_gains import SlaveControl
from rig.runs.run import AbortRun


class TensionHold:
    """The loop's step, and the log the report's figures are computed from (`log`, per tick)."""

    def __init__(self, controller, loop, live, cfg, n_ticks: int, t_start: float, tension: np.ndarray,
                 estimate, on_model: bool = False):
        self.c = controller
        self.estimate = estimate
        self.on_model = on_model
        self.loop = loop
        self.live = live
        self.names = list(controller.arms)
        self.t_start = t_start
        self.tension = tension
        self.cell_rate = cfg.loadcell["rate"]
        self.max_force_age = max(2.0 / self.cell_rate, 2.0 / loop.clock.rate)
        self.stale_timeout = cfg.loadcell["stale_timeout"]
        # With the impedance in the arm a late tension only holds the set-point where it is
        # (the arm keeps the slaves in place): samples that reach the loop late, the cell
        # still streaming, are then waited for as long as the arms' own streams are
        self.loop_stale = (max(self.stale_timeout, *(cfg.arms[n]["watchdog"] for n in self.names))
                           if controller.slave_control == SlaveControl.ARM else self.stale_timeout)
        self.blind_ticks, self.blind_longest = 0, 0.0
        self._t_last_tick: float | None = None
        self.log = {"t": np.empty(n_ticks), "tension": np.empty((n_ticks, len(controller.elements))),
                    "setpoint": np.empty(n_ticks), "loop_us": np.empty(n_ticks),
                    "x_f": np.empty((n_ticks, len(controller.slaves))), "force_offset": np.empty(n_ticks),
                    "tension_estimate": np.empty((n_ticks, len(controller.elements))),
                    "estimate_spread": np.empty((n_ticks, len(controller.elements))),
                    "estimate_torques": np.empty((n_ticks, len(controller.elements))),
                    "estimate_ambiguous": np.zeros(n_ticks, bool)}
        for n in self.names:
            self.log[f"{n}.x"] = np.empty((n_ticks, 3))
            self.log[f"{n}.xd"] = np.empty((n_ticks, 3))

    def _judge_tension(self, tick) -> tuple[np.ndarray | None, np.ndarray | None, bool]:
        """(fresh tension or None, its times, blind): a tick late itself (this process held)
        finds samples as old as the gap: they are the newest there are, not a stalled cell.
        The model's estimate is updated, recorded and logged; closing on it, it is the fresh
        tension (and, with no load cell, the tension)."""
        t, sensors = tick.t, self.loop.sensors
        newest = [new[-1] if new else None for new in tick.forces]
        fresh = fresh_t = None
        if sensors and all(s is not None for s in newest):
            self.tension = np.array([s.force for s in newest])
            fresh, fresh_t = self.tension, np.array([s.t for s in newest])
        force_age = t - min(self.loop.newest_force_t) if sensors else 0.0
        gap = t - self._t_last_tick if self._t_last_tick is not None else 0.0
        self._t_last_tick = t
        blind = force_age > max(self.max_force_age, gap + 1.0 / self.cell_rate)
        if blind:
            self.blind_ticks += 1
            self.blind_longest = max(self.blind_longest, force_age)
            if force_age > self.stale_timeout:
                check_stale_tension(sensors, force_age, self.stale_timeout, self.loop_stale,
                                    self.cell_rate, "[loadcell] stale_timeout")
        # every joint sample since the last tick: the observer integrates the efforts
        est = self.estimate.update({n: tick.joint_samples.get(n) or tick.js[n] for n in self.names},
                                   1.0 / self.loop.clock.rate)
        rec = self.loop.recorder
        for k_el, value in enumerate(est):
            suffix = str(k_el) if k_el else ""
            rec.scalar(figures.TENSION_ESTIMATE_TOPIC + suffix, t, float(value))
            rec.scalar(figures.TENSION_TORQUES_TOPIC + suffix, t, float(self.estimate.torque_tension[k_el]))
            rec.scalar(figures.TENSION_SPREAD_TOPIC + suffix, t, float(self.estimate.spread[k_el]))
        self.log["tension_estimate"][tick.k] = est
        self.log["estimate_spread"][tick.k] = self.estimate.spread
        self.log["estimate_torques"][tick.k] = self.estimate.torque_tension
        self.log["estimate_ambiguous"][tick.k] = self.estimate.ambiguous
        if self.on_model:
            # the loop closes on the estimate: as fresh as the joint states it came from
            fresh, fresh_t, blind = est, stamps(tick.js, len(est)), False
            if not sensors:
                self.tension = est
        return fresh, fresh_t, blind

    def step(self, tick) -> dict:
        t, js, c = tick.t, tick.js, self.c
        fresh, fresh_t, blind = self._judge_tension(tick)
        self.live.poll(t)
        q = {n: js[n].position[:3] for n in self.names}
        dq = {n: js[n].velocity[:3] for n in self.names}
        with tick.timed():
            # the samples' own times: the loop's ticks are not `dt` apart over the wire
            commands = c.step(t, q, dq, fresh, blind=blind, stamps={n: js[n].t for n in self.names},
                              tension_t=fresh_t)
        xd, _, _ = c.desired(t)
        # recorded before the loop's checks: an aborted run's recording holds the tick that
        # broke a limit
        rec = self.loop.recorder
        rec.scalar(figures.SETPOINT_TOPIC, t, c.force_setpoint)
        for n in self.names:
            tick.tips[n] = c.tip_world(n, q[n])
            rec.point(figures.measured_cp_topic(n), js[n].t, tick.tips[n], "world")
            rec.point(figures.setpoint_cp_topic(n), t, xd[n], "world")
        tick.tension = float(self.tension.max())
        self._log(tick, xd)
        return commands

    def _log(self, tick, xd: dict) -> None:
        k, log, c = tick.k, self.log, self.c
        for n in self.names:
            log[f"{n}.x"][k] = tick.tips[n]
            log[f"{n}.xd"][k] = xd[n]
        log["t"][k] = tick.t - self.t_start
        log["tension"][k] = self.tension
        log["setpoint"][k] = c.force_setpoint
        log["force_offset"][k] = c.applied_force_offset
        log["loop_us"][k] = tick.compute_s * 1e6
        log["x_f"][k] = [c.x_f[s] for s in c.slaves]
        self.loop.recorder.scalar("/cooperative/x_f", tick.t, float(log["x_f"][k][0]))

    def show(self, tick) -> None:
        """The live display (--interactive), every progress update."""
        self.live.show(tick.t - self.t_start, float(self.tension.mean()),
                       {n: self.log[f"{n}.x"][tick.k] for n in self.names})


@contextmanager
def plot_hint(run, timing=None):
    """A loop cut short (an abort, Ctrl-C, a fault) draws no figure: say how to see it, and
    leave the loop's timing so far (`timing()`) in the run's result (result.json of an
    aborted run then says whether the machine kept time)."""
    try:
        yield
    except BaseException:
        run.say(f"the figures of this run up to where it stopped: rig plot {run.dir}")
        if timing is not None and run.result is None:
            try:
                run.result = {"loop_timing": timing()}
            except Exception:  # noqa: BLE001 - the abort's own reason is the one to report
                pass
        raise


class ServoCI:
    """Sends the slaves' arm-impedance commands as the dVRK's servo_ci (rig.control.arm_impedance),
    with the tool-tip orientation held where it was when the loop started."""

    def __init__(self, rig, slaves):
        from rig.model.psm_arm_kinematics import PSMKinematics

        self.arms = {n: rig.arms[n] for n in slaves}
        self.kinematics = PSMKinematics()
        self.hold = {n: self.kinematics.forward(self.arms[n].measured_arm()[0][:6])[:3, :3] for n in slaves}

    def send(self, n: str, cmd, t: float, rec) -> None:
        from rig.control.arm_impedance import servo_ci_goal

        arm = self.arms[n]
        q = arm.measured_arm()[0][:6]
        g = servo_ci_goal(self.kinematics, q, cmd.target, cmd.velocity, cmd.u, cmd.stiffness, cmd.damping,
                          cmd.feedforward, orientation=self.hold[n])
        arm.servo_ci(g.position, g.orientation, g.stiffness, g.damping, g.bias,
                     torque_stiffness=g.torque_stiffness, torque_damping=g.torque_damping, torque_bias=g.torque_bias,
                     force_orientation=g.force_orientation)
        rec.pose(f"/{n}/servo_ci/goal", t, g.position, (0.0, 0.0, 0.0, 1.0))
        rec.wrench(f"/{n}/servo_ci/bias", t, g.force_orientation @ g.bias)


def check_stale_tension(sensors, age: float, timeout: float, loop_limit: float, rate: float, setting: str) -> None:
    """The newest tension at the loop is `age` s old, beyond the stale `timeout`: end the
    run if the cell fell silent (its driver saw no sample for longer than `timeout`), or
    if samples have not reached the loop for longer than `loop_limit` while the cell
    still streamed (this process held off the CPU); else keep holding."""
    from rig.faults import silence_text, starved_text

    silent = max(s.stream_age() for s in sensors)
    if silent <= timeout and age <= loop_limit:
        return
    cells = ", ".join(str(s.name or f"element {k}") for k, s in enumerate(sensors))
    if silent > timeout:
        raise AbortRun(f"load cell stale: {silence_text(silent, rate, 'sample')}, beyond the stale timeout "
                       f"{1000 * timeout:.0f} ms ({setting}). " + starved_text(
                           setting, f"the cell{'s' if len(sensors) > 1 else ''} ({cells}) are plugged in and powered "
                           "(or `rig sim` runs)", "check the cable and power"))
    raise AbortRun(f"load cell stale: no sample reached the control loop for {1000 * age:.0f} ms "
                   f"(limit {1000 * loop_limit:.0f} ms) while the cell{'s' if len(sensors) > 1 else ''} "
                   f"({cells}) still streamed at {rate:g} Hz: this process was held off the CPU, the machine is too "
                   f"busy for the loop (free a CPU or raise {setting}; the force loop held meanwhile)")

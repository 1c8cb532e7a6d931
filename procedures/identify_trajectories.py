"""The trajectories of `rig identify`: designed on the arm's simulated twin, reached, streamed and checked."""

from __future__ import annotations

import bisect
import collections

import numpy as np

from rig.control.arm_command import ArmCommand, CommandKind
from rig.runs.control_loop import ControlLoop
from rig.runs.run import AbortRun


def design_settings(parameters: dict) -> dict:
    """The options the trajectories depend on (calibration.excitation_design.design's settings)."""
    return {"frequency_hz": parameters["frequency"], "harmonics": parameters["harmonics"],
            "duration": parameters["duration"], "starts": parameters["starts"], "iterations": parameters["iterations"],
            "seed": parameters["design_seed"], "velocity_fraction": parameters["velocity_fraction"],
            "validation_frequency_hz": parameters["validation_frequency"], "fill": parameters["fill"]}


def plant_of(cfg, arm_name: str):
    """The simulated twin of `arm_name` at the rig rate (what the margins are measured on):
    the configured parameters, effects, PID, effort limit and sensors, whatever its driver."""
    from calibration.excitation_design import Plant
    from rig.sim.world import world_from_config

    world = world_from_config(cfg, [arm_name], with_object=False, seed=0)
    return Plant(world.arms[arm_name].spec, float(cfg.rig["rate"]), np.asarray(cfg.rig["gravity"], float), 0)


def design_excitation(parameters: dict, gravity: np.ndarray, plant, progress=None, processes: int | None = None) -> dict:
    """The optimised excitation and the validation trajectory for these settings, each kept
    clear of Table 4.2's limits by the margin measured on `plant` (calibration.
    excitation_design), from the user's cache when designed before (see its docstring)."""
    from calibration.excitation_design import design
    from rig.model.psm_kinematics import DQ_MAX, Q_MAX, Q_MIN

    return design(design_settings(parameters), gravity, plant, Q_MIN, Q_MAX, DQ_MAX, progress=progress,
                  processes=processes)


def validation_trajectory(frequency_hz: float, duration: float, harmonics: int, seed: int, fill: float):
    """The validation trajectory before its margin (calibration.excitation_design.validation_trajectory
    at Table 4.2's limits)."""
    from calibration.excitation_design import validation_trajectory as raw
    from rig.model.psm_kinematics import DQ_MAX, Q_MAX, Q_MIN

    return raw(frequency_hz, duration, harmonics, seed, fill, Q_MIN, Q_MAX, DQ_MAX)


#: Close enough to a trajectory's start to begin streaming (rad, rad, m): the first
#: servo_jp set-points then differ from the measured joints by less than the PID's
#: usual tracking error (a loaded joint can rest a few mrad short under the dVRK PID).
START_TOLERANCE = np.array([0.02, 0.02, 0.005])


def reach_start(arm, goal, what: str, say) -> None:
    """move_jp to ``goal``; accept arrival within START_TOLERANCE, else abort the run."""
    if arm.move_jp(goal, wait=True, timeout=20.0):
        return
    q = np.asarray(arm.measured_js().position[:3], float)
    off = np.abs(q - goal)
    if np.all(off <= START_TOLERANCE):
        say(f"start of the {what} trajectory reached within {np.round(off, 4).tolist()} (rad, rad, m)")
        return
    raise AbortRun(f"{arm.name} did not reach the start of the {what} trajectory within 20 s "
                   f"(off by {np.round(off, 4).tolist()} rad, rad, m)")


def stream_trajectory(run, arm, clock, traj, topic_prefix: str, step, limits, margin) -> dict:
    """servo_jp the trajectory (position and velocity feed-forward) at the clock rate,
    recording measured_js; returns arrays and what the arm met.

    Aborts the run (the engine holds the arm) as soon as a measured joint comes within
    ABORT_FRACTION of its margin of a position limit, or faster than its velocity limit
    less that fraction of its velocity margin (calibration.excitation_design): before the
    limit, where the console would fault. The trajectory's time waits while its set-point
    leads the arm by more than the margin's lag (calibration.excitation_design.lagging).
    The run engine's control loop ticks, drains every sample the arm sent into the
    recording and sends the commands (rig.runs.control_loop); `_Streamer.step` is its step.
    """
    streamer = _Streamer(arm, clock.rate, traj, topic_prefix, step, limits, margin)
    loop = ControlLoop(run, clock, {arm.name: arm}, read="drain")
    arm.drain_js()  # what arrived before the trajectory starts is not part of it
    loop.send(streamer.command(0, clock.now()), clock.now())
    loop.run(streamer.step)
    step.update(streamer.n)
    return streamer.result(limits)


class _Streamer:
    """The trajectory's loop step: judge the newest samples, advance the trajectory's time
    or wait for the arm, command the next set-point."""

    def __init__(self, arm, rate: float, traj, topic_prefix: str, step, limits, margin):
        self.arm, self.rate, self.topic_prefix, self.progress, self.limits, self.margin = (
            arm, rate, topic_prefix, step, limits, margin)
        self.n = int(round(traj.duration * rate)) + 1
        self.q_cmd, self.dq_cmd, _ = traj.sample(np.arange(self.n) / rate)
        self.low, self.high, self.speed = margin.abort_limits(limits.q_min, limits.q_max, limits.dq_max)
        self.samples, self.sent, self.sent_t = [], [], []
        self.every = max(1, self.n // 100)
        self.ticks_without = self.waited = 0
        self.q_last = self.t_last = self.rest_offset = None
        self.silent_after = SILENT * max(1.0 / rate, _stream_period(arm))
        # the least (now - stamp) over the last DELAY_WINDOW ticks: transport plus any offset of
        # the two clocks. A window, not the whole run: samples taken in a burst when the loop
        # starts may be stamped ahead of this process's clock (on simulated time the world ran
        # ahead while it waited), and a delay of the run's first ticks would hold its time for good
        self.delays: collections.deque = collections.deque(maxlen=max(1, int(DELAY_WINDOW * rate)))
        self.delay = np.inf
        self.k = 0

    def command(self, k: int, t: float) -> dict:
        self.sent.append((t, k))
        self.sent_t.append(t)
        return {self.arm.name: ArmCommand(CommandKind.POSITION, q=self.q_cmd[k], dq=self.dq_cmd[k])}

    def step(self, tick) -> dict | None:
        self._see(tick.t, tick.joint_samples[self.arm.name])
        if self._waits(tick.t):
            self.waited += 1
        else:
            self.k += 1
            if self.k % self.every == 0:
                self.progress.update(self.k)
        return self.command(self.k, tick.t) if self.k < self.n else None

    def _see(self, t: float, new: list) -> None:
        """Every sample the arm sent since the last tick: a tick held up by the machine finds
        several, and the fit still gets the stream whole."""
        self.ticks_without += not new
        for js in new:
            self.samples.append((js.t, js.position[:3], js.velocity[:3], js.effort[:3]))
        if not new:
            return
        self.t_last = new[-1].t
        self.delays.append(t - self.t_last)
        self.delay = min(self.delays)
        self.q_last, dq = np.asarray(new[-1].position[:3]), np.asarray(new[-1].velocity[:3])
        low, high, speed = self.low, self.high, self.speed
        if np.any(self.q_last < low) or np.any(self.q_last > high) or np.any(np.abs(dq) > speed):
            raise AbortRun(f"{self.arm.name} during the {self.topic_prefix} trajectory at t = {self.k / self.rate:.2f} s: "
                           f"{_abort_reason(self.q_last, dq, low, high, speed, self.limits, self.margin)}; "
                           "the arm is held")

    def _waits(self, t: float) -> bool:
        """The trajectory's time waits while the arm's newest sample is older than usual (it
        is silent, or its process fell behind and catches up: over the wire a served arm
        held off the CPU for 0.5 s applied the commands queued meanwhile at once), or while
        the set-point in force at that sample's stamp leads it by more than the margin's lag:
        an arm whose commands stopped arriving then meets, when they resume, a set-point a
        lag ahead, not one that ran on by the stall times the speed
        (calibration.excitation_design). The set-point of the sample's own time leaves the
        transport delay out of the lag. The lead is counted from where the arm rested at the
        start: a loaded joint rests a few mrad short of its set-point under the PID
        (START_TOLERANCE), and that offset alone held the trajectory at its start for good
        (seen over the wire: q2 2.3 mrad short, 380 000 periods waited)."""
        from calibration.excitation_design import lagging

        k = self.k
        then = self.sent[max(0, bisect.bisect_right(self.sent_t, self.t_last) - 1)][1] if self.t_last is not None else k
        if self.rest_offset is None and self.q_last is not None:
            self.rest_offset = self.q_cmd[0] - self.q_last
        return bool((self.t_last is not None and t - self.t_last - self.delay > self.silent_after) or (
            self.q_last is not None and lagging(self.q_last + self.rest_offset, self.q_cmd[then], self.dq_cmd[then],
                                                self.margin.lag)))

    def result(self, limits) -> dict:
        if not self.samples:
            raise AbortRun(f"{self.arm.name}: no measured_js during the {self.topic_prefix} trajectory")
        rate, samples = self.rate, self.samples
        T = np.array([s[0] for s in samples])
        Q, DQ, TAU = (np.array([s[i] for s in samples], float) for i in (1, 2, 3))
        sent_k = np.array([x[1] for x in self.sent])
        met = tracking_met(T, Q, DQ, np.array(self.sent_t), self.q_cmd[sent_k], self.dq_cmd[sent_k], limits)
        met["periods_waited_for_the_arm"] = self.waited
        # Keep each sample once (time must increase), and put them on a uniform grid of their
        # own stamps (the arm's sample times), which the filtering and the decimation assume:
        # over the wire the samples jitter, and a gap (a publisher held up) is interpolated.
        keep = np.concatenate([[True], np.diff(T) > 0])
        t, q, dq, tau = T[keep], Q[keep], DQ[keep], TAU[keep]
        if len(t) > 1 and not np.allclose(np.diff(t), 1.0 / rate, rtol=1e-3, atol=1e-6):
            grid = t[0] + np.arange(int(np.floor((t[-1] - t[0]) * rate)) + 1) / rate

            def on_grid(x):
                return np.column_stack([np.interp(grid, t, x[:, j]) for j in range(x.shape[1])])

            t, q, dq, tau = grid, on_grid(q), on_grid(dq), on_grid(tau)
        return {"t": t, "q": q, "dq": dq, "tau": tau, "rate": rate, "ticks_without_sample": self.ticks_without,
                "met": met}


#: Loop or arm periods (the longer) by which the arm's newest sample may be older than the
#: least delay seen before the trajectory's time waits for the arm (stream_trajectory).
SILENT = 5.0
#: s of ticks over which the transport delay is the least seen (`stream_trajectory`)
DELAY_WINDOW = 0.5


def _stream_period(arm) -> float:
    """s between the arm's measured_js messages as it publishes them (0 when it does not say)."""
    r = arm.published_rate()
    return 1.0 / r if r > 0 else 0.0


def _abort_reason(q, dq, low, high, speed, limits, margin) -> str:
    for j in range(3):
        u = "m" if j == 2 else "rad"
        if q[j] < low[j] or q[j] > high[j]:
            edge = limits.q_min[j] if q[j] < low[j] else limits.q_max[j]
            return (f"joint {j + 1} at {q[j]:.4f} {u}, {abs(q[j] - edge) * (1e3 if j == 2 else 1):.4g} "
                    f"{'mm' if j == 2 else u} from its limit {edge:g} {u} (the excitation keeps "
                    f"{margin.position[j] * (1e3 if j == 2 else 1):.4g} {'mm' if j == 2 else u}: the arm tracks worse "
                    f"than the {margin.tracking_position[j] * (1e3 if j == 2 else 1):.3g} measured on its simulated plant; "
                    "check its PID gains and load, or lower --velocity-fraction)")
    for j in range(3):
        if abs(dq[j]) > speed[j]:
            u = "m/s" if j == 2 else "rad/s"
            where = ("above" if abs(dq[j]) > limits.dq_max[j] else
                     f"within {limits.dq_max[j] - abs(dq[j]):.3g} {u} of")
            return (f"joint {j + 1} velocity {dq[j]:.3f} {u}, {where} its limit {limits.dq_max[j]:g} {u} "
                    f"(the excitation keeps {margin.velocity[j]:.3g} {u}: the arm tracks "
                    f"worse than measured on its simulated plant; lower --velocity-fraction)")
    return "limit"


def tracking_met(T, Q, DQ, sent, q_cmd, dq_cmd, limits) -> dict:
    """What the arm met during a streamed trajectory, per joint: ``position_tracking`` and
    ``velocity_tracking``, max |q - q_cmd| and |dq - dq_cmd| against the newest set-point
    sent before each sample's stamp (over the wire the two clocks are the same machine's
    or NTP's: a few ms of offset read as dq x offset); ``overshoot`` how far q went beyond
    the commanded range and ``velocity_excess`` max |dq| - max |dq_cmd| (neither depends on
    timing); ``closest_to_position_limit`` (rad, rad, m) and ``peak_velocity_fraction`` of
    Table 4.2's limit."""
    k = np.clip(np.searchsorted(sent, T, side="right") - 1, 0, len(sent) - 1)
    over = np.maximum(q_cmd.min(axis=0) - Q.min(axis=0), Q.max(axis=0) - q_cmd.max(axis=0))
    return {"position_tracking": np.abs(Q - q_cmd[k]).max(axis=0).tolist(),
            "velocity_tracking": np.abs(DQ - dq_cmd[k]).max(axis=0).tolist(),
            "overshoot": over.tolist(),
            "velocity_excess": (np.abs(DQ).max(axis=0) - np.abs(dq_cmd).max(axis=0)).tolist(),
            "closest_to_position_limit": np.minimum(Q.min(axis=0) - limits.q_min, limits.q_max - Q.max(axis=0)).tolist(),
            "peak_velocity_fraction": (np.abs(DQ).max(axis=0) / limits.dq_max).tolist()}

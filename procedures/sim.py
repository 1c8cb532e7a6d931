"""`rig sim`: serve the simulated rig over the real device protocols, like the dVRK's
simulation mode.

One process, paced to the wall clock:

* every simulated arm as the dVRK 2.3 CRTK topics under /<arm>: measured_js at the rig
  rate (default 1 kHz); setpoint_js, measured_cp, local/measured_cp and body/measured_cf
  at `--cp-rate` (default 100 Hz, the dVRK ROS bridge's default publishing rate, which
  also keeps the CPU budget for the 1 kHz stream), each while it has a subscriber (looked
  up at 10 Hz); servo_jp, servo_jf and move_jp are subscribed and drive
  `drivers.sim_arm.SimArm` (the same fake the in-process tests use, trajectory generator
  included), behind the dVRK's operating state (`drivers.sim_arm_state.SimArmState`:
  each arm starts DISABLED and not homed, is enabled and homed on <arm>/state_command,
  drops motion commands unless ENABLED and homed with the dVRK's throttled warning, is
  busy during a homing and a move_jp, faults on a joint past its limit and, once a test
  arms it, on servo commands that stop); crtk_msgs/OperatingState on
  <arm>/operating_state at 100 Hz and on every change, the arm's warnings and errors
  on <arm>/warning and <arm>/error (std_msgs/String, as the dVRK) and in this process's
  log; <console>/power_on, power_off and home send enable, disable and home to every
  arm, with <console> /console as dVRK 2.3 or /system as 2.4 (`--console`);
* the mocap system as geometry_msgs/PoseStamped on /<prefix>/<body>/pose at the mocap
  rate (default 120 Hz), running while any body's topic has a subscriber, from
  `drivers.mocap_sim.SimTracker` (noise, occlusion, latency; quaternions on the wire are
  geometry_msgs' (x, y, z, w)); an occluded body is simply not published in that frame,
  as mocap bridges do;
* with `--natnet`, the mocap system as OptiTrack Motive's NatNet stream as well
  (`drivers.natnet_server.SimMotive`: its own SimTracker, FakeMotive's bytes) on the
  loopback at [mocap] server, command_port and data_port, unicast or to [mocap] multicast,
  stamped on the same timeline as the ROS messages;
* the operator's side channel (`drivers.operator`): the manual steps of a procedure done
  by the simulation, and the faults a test injects (the load cell's cable pulled, an
  arm's joint pushed past its limit, an arm's servo watchdog armed);
* the load cell: `drivers.loadcell.FakeLoadCellFirmware`, each in its own process
  (`drivers.loadcell_process`), on a pseudo-terminal per object
  element, fed by its tension or a hanging mass (printed as `loadcell: /dev/pts/N`; open
  it with pyserial; the configured [loadcell] port becomes a link to it when free).

Threads: the main thread steps the world, publishes and paces (sleeps to
`start + k / rate`); an executor thread spins the node for the subscriptions, whose
callbacks only queue commands that the main thread applies before the next step, so the
world is only ever touched by one thread; the firmware fake has its own thread. Header
stamps are `wall time at start + simulated time`. Publishers use the default QoS of the
dVRK (reliable, depth 10).

Prints `ready` when serving, and the achieved measured_js rate at exit (SIGINT/SIGTERM or
--duration).
"""

from __future__ import annotations

import dataclasses
from array import array
import os
from pathlib import Path
import signal
import sys
import threading
import time
from collections import deque

import click

#: s behind the wall clock beyond which the served rig re-anchors its time instead of catching up
REANCHOR = 0.5

STEPS = ("build the simulated world", "start the load cell on a pty", "create the ROS 2 node and topics",
         "serve until stopped")


def _say(text: str) -> None:
    print(text, flush=True)


class SimServer:
    """The simulated rig served on a ROS 2 node (see the module docstring).

    world: a `rig.sim.SimWorld` (its own pacing is turned off: the server paces);
    node: an rclpy Node, spun here on an executor thread; arms: names to serve;
    cp_rate: Hz of the slower arm topics; mocap: a dict with prefix, rate, noise, latency,
    occlusion (or None for no mocap); console: the console's namespace ("/console" as in
    dVRK 2.3, "/system" as in 2.4); cells: the `CellLoad`s of the served load cells, the
    configured one first (the operator hangs masses from it).
    """

    def __init__(self, world, node, arms: list[str], cp_rate: float = 100.0, mocap: dict | None = None,
                 seed: int = 0, console: str = "/console", cells: list | None = None, executor: str = "events"):
        from crtk_msgs.msg import OperatingState, StringStamped
        from geometry_msgs.msg import PoseStamped, WrenchStamped
        from rclpy.qos import QoSProfile
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Empty, String

        from drivers.crtk import PSM_JOINT_NAMES
        from drivers.sim_arm_state import OPERATING_STATE_RATE, SimArmState
        from rig.clock import SimClock
        from drivers.sim_arm import SimArm

        self.world = world
        world.pace = False
        self.node = node
        self.clock = SimClock(world)
        self.arms = {n: SimArm(world, n, self.clock) for n in arms}
        self.states = {n: SimArmState(self.arms[n]) for n in arms}
        self.rate = self.clock.rate
        self.cp_every = max(1, int(round(self.rate / cp_rate)))
        self.state_every = max(1, int(round(self.rate / OPERATING_STATE_RATE)))
        self._refresh_every = max(1, int(round(0.1 * self.rate)))  # subscribers looked up at 10 Hz
        self._commands: deque = deque()
        self._Msg = {"js": JointState, "pose": PoseStamped, "wrench": WrenchStamped, "state": OperatingState,
                     "string": String}
        self._state_pub = {}
        qos = QoSProfile(depth=10)
        names = list(PSM_JOINT_NAMES[:3])
        self._pub = {}
        self._msgs = {}
        for n in arms:
            ns = "/" + n
            self._pub[n] = {
                "measured_js": node.create_publisher(JointState, f"{ns}/measured_js", qos),
                "setpoint_js": node.create_publisher(JointState, f"{ns}/setpoint_js", qos),
                "measured_cp": node.create_publisher(PoseStamped, f"{ns}/measured_cp", qos),
                "local/measured_cp": node.create_publisher(PoseStamped, f"{ns}/local/measured_cp", qos),
                "body/measured_cf": node.create_publisher(WrenchStamped, f"{ns}/body/measured_cf", qos),
            }
            m = JointState()
            m.name = names
            m.header.frame_id = n
            self._msgs[n] = m
            state = self.states[n]
            node.create_subscription(JointState, f"{ns}/servo_jp", self._queued(self._servo_jp, state), qos)
            node.create_subscription(JointState, f"{ns}/servo_jf", self._queued(self._servo_jf, state), qos)
            node.create_subscription(JointState, f"{ns}/move_jp", self._queued(self._move_jp, state), qos)
            node.create_subscription(StringStamped, f"{ns}/state_command", self._queued(self._state_command, state),
                                     qos)
            self._state_pub[n] = {k: node.create_publisher(t, f"{ns}/{k}", qos) for k, t in
                                  (("operating_state", OperatingState), ("warning", String), ("error", String))}
        self.console = "/" + console.strip("/")
        for what in ("power_on", "power_off", "home"):
            node.create_subscription(Empty, f"{self.console}/{what}", self._queued(self._console, what), qos)
        from drivers.operator_sim import OperatorServer, SimOperator

        # the operator's side channel: what a person does by hand, done by the simulation
        self.operator = OperatorServer(SimOperator(world, self.arms, cell=(cells or [None])[0],
                                                   cells={c.element: c for c in cells or []}, states=self.states),
                                       node)
        self.cells = list(cells or [])
        self.tracker = None
        self.natnet = None  # a drivers.natnet_server.SimMotive when serving NatNet (`--natnet`)
        self._mocap_msg: dict = {}
        self._mocap_pub: dict = {}
        self._mocap = mocap
        self._seed = seed
        if mocap is not None:
            from drivers.mocap import pose_topic
            from rig.sim import default_marker_bodies

            bodies = [mb.name for n in world.names for mb in default_marker_bodies(n)] + ["world"]
            self._mocap_pub = {b: node.create_publisher(PoseStamped, pose_topic(mocap["prefix"], b), qos)
                               for b in bodies}
        # Topics nobody subscribes to are not computed nor published (the cameras run while
        # someone watches): measured_js always, the others once a subscriber appears.
        self._watched = {n: set() for n in arms}
        self._refresh_watched()
        self.published = {n: 0 for n in arms}
        self.command_errors = 0
        self.state_commands = 0
        self.superseded = 0
        self.max_lag = 0.0  # s, the longest the loop fell behind the wall clock
        self._last_command: dict[str, int] = {}
        self.late_ticks = 0
        self.slips = 0
        self.stop = threading.Event()
        from rig.ros_session import make_executor

        self._executor = make_executor(executor, node.context)
        self._executor.add_node(node)
        self._spin_thread = threading.Thread(target=self._spin, name="sim-executor", daemon=True)

    # -- subscriptions (executor thread): queue, never touch the world -----------------
    def _spin(self) -> None:
        try:
            while not self.stop.is_set():  # spin_once in a loop: see make_executor
                self._executor.spin_once(timeout_sec=0.005)
        except Exception:  # noqa: BLE001 - the context was shut down while stopping
            if not self.stop.is_set():
                raise

    def _queued(self, fn, arg):
        def callback(msg) -> None:
            self._commands.append((time.perf_counter(), fn, arg, msg))
        return callback

    # motion commands go through the arm's operating state: True when obeyed
    def _servo_jp(self, state, m) -> bool:
        return state.servo_jp(m.position, m.velocity if len(m.velocity) >= 3 else None, self.world.t)

    def _servo_jf(self, state, m) -> bool:
        return state.servo_jf(m.effort, self.world.t)

    def _move_jp(self, state, m) -> bool:
        return state.move_jp(m.position, self.world.t)

    def _state_command(self, state, m) -> None:
        self.state_commands += 1
        state.command(str(m.string), self.world.t)

    def _console(self, what, _msg) -> None:
        # the console's buttons act on every arm, through each arm's state machine
        command = {"power_on": "enable", "power_off": "disable", "home": "home"}[what]
        for state in self.states.values():
            state.command(command, self.world.t)

    def _apply_commands(self, until: float = float("inf")) -> None:
        """Apply the commands received up to perf_counter time `until`: the wall time the
        next step stands for. When the loop runs behind and catches up step by step, each
        command then acts at the step of its arrival, as on an arm that never fell behind,
        instead of the newest of a burst jumping the set-point forward."""
        self.operator.apply()
        commands = self._commands
        while commands and commands[0][0] <= until:
            _, fn, arg, msg = commands.popleft()
            if fn in (self._servo_jp, self._servo_jf, self._move_jp):
                # DDS keeps order within a topic only: a servo command sent before a move_jp
                # (a hold) may arrive after it and would cancel the move. One client stamps
                # its commands on one clock, so a command older than the arm's last one is
                # superseded: dropped and counted.
                stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
                if stamp and stamp < self._last_command.get(arg.name, 0):
                    self.superseded += 1
                    continue
                if stamp:
                    self._last_command[arg.name] = stamp
            try:
                obeyed = fn(arg, msg)
            except ValueError as exc:  # a malformed command is refused, reported, counted
                self.command_errors += 1
                self.node.get_logger().warning(f"command refused: {exc}")
                continue
            if obeyed:
                self.operator.operator.release(arg.name)  # the client takes the arm over

    # -- publishing (main thread) ---------------------------------------------------------
    def _stamp(self, msg, t: float) -> None:
        ns = int(round((self._epoch0 + t) * 1e9))
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 1_000_000_000)

    def _publish_js(self, name: str, t: float) -> None:
        q, dq, effort = self.world.measured_js(name)
        m = self._msgs[name]
        self._stamp(m, t)
        # array('d') skips the generated setters' per-element checks (a third of the cost).
        m.position, m.velocity, m.effort = array("d", q), array("d", dq), array("d", effort)
        self._pub[name]["measured_js"].publish(m)
        self.published[name] += 1

    def _publish_states(self, t: float, every: bool) -> None:
        """Each arm's operating_state when it changed (or `every`), and its messages."""
        for name, state in self.states.items():
            if every or state.changed:
                state.changed = False
                st = state.operating_state()
                m = self._Msg["state"]()
                self._stamp(m, t)
                m.header.frame_id = name
                m.state, m.is_homed, m.is_busy = st.state, st.is_homed, st.is_busy
                self._state_pub[name]["operating_state"].publish(m)
            while state.messages:
                level, text = state.messages.pop(0)
                # (one call site per severity: rclpy ties a call site to its first severity)
                if level == "error":
                    self.node.get_logger().error(text)
                else:
                    self.node.get_logger().warning(text)
                self._state_pub[name][level].publish(self._Msg["string"](data=text))

    def _refresh_watched(self) -> None:
        """Which of the slower topics have subscribers; start or stop the mocap system to match."""
        for name, pubs in self._pub.items():
            self._watched[name] = {k for k, p in pubs.items() if k != "measured_js" and p.get_subscription_count() > 0}
        watched = any(p.get_subscription_count() > 0 for p in self._mocap_pub.values())
        if watched and self.tracker is None:
            from drivers.mocap_sim import SimTracker

            m = self._mocap
            self.tracker = SimTracker(self.world, self.clock, noise=m["noise"], latency=m["latency"],
                                      occlusion=m["occlusion"], rate=m["rate"], quaternion_order="xyzw",
                                      seed=self._seed + 1)
        elif not watched and self.tracker is not None:
            self.tracker.close()
            self.tracker = None

    def _publish_slow(self, name: str, t: float) -> None:
        from drivers.quaternion import matrix_to_quat_xyzw

        watched = self._watched[name]
        if not watched:
            return
        arm, pub, Msg = self.arms[name], self._pub[name], self._Msg
        if "setpoint_js" in watched:
            sp = arm.setpoint_js()
            m = Msg["js"]()
            m.name = list(arm.joint_names)
            m.header.frame_id = name
            self._stamp(m, t)
            m.position, m.velocity, m.effort = sp.position.tolist(), sp.velocity.tolist(), sp.effort.tolist()
            pub["setpoint_js"].publish(m)
        if watched & {"measured_cp", "local/measured_cp"}:
            cp = arm.measured_cp()
            pm = Msg["pose"]()
            self._stamp(pm, t)
            pm.header.frame_id = cp.frame
            pm.pose.position.x, pm.pose.position.y, pm.pose.position.z = cp.position.tolist()
            o = pm.pose.orientation
            o.x, o.y, o.z, o.w = matrix_to_quat_xyzw(cp.rotation).tolist()  # geometry_msgs order
            pub["measured_cp"].publish(pm)
            pub["local/measured_cp"].publish(pm)  # no base frame on a simulated PSM: the same pose
        if "body/measured_cf" in watched:
            cf = arm.body_measured_cf()
            wm = Msg["wrench"]()
            self._stamp(wm, t)
            wm.header.frame_id = cf.frame
            wm.wrench.force.x, wm.wrench.force.y, wm.wrench.force.z = cf.force.tolist()
            wm.wrench.torque.x, wm.wrench.torque.y, wm.wrench.torque.z = cf.torque.tolist()
            pub["body/measured_cf"].publish(wm)

    def _publish_mocap(self) -> None:
        for frame in self.tracker.frames():
            for body, pose in frame.bodies.items():
                if pose is None:
                    continue  # occluded: bridges publish nothing for a lost body
                pm = self._mocap_msg.get(body)
                if pm is None:  # one message object per body, refilled (publish copies it)
                    pm = self._mocap_msg[body] = self._Msg["pose"]()
                    pm.header.frame_id = "world"
                self._stamp(pm, frame.t)
                pm.pose.position.x, pm.pose.position.y, pm.pose.position.z = pose.position.tolist()
                q = frame.quaternions[body]  # frame.quaternion_order == "xyzw", as on the wire
                o = pm.pose.orientation
                o.x, o.y, o.z, o.w = (float(v) for v in q)
                self._mocap_pub[body].publish(pm)

    # -- the loop -------------------------------------------------------------------------
    def serve(self, duration: float | None = None, on_ready=None) -> dict:
        """Step, publish and pace until `stop` is set or `duration` s of sim time passed."""
        self._spin_thread.start()
        world = self.world
        # One untimed tick first: loading the compiled physics kernel and the first
        # publications take a fraction of a second that would count as a stall.
        self.clock.tick()
        self._epoch0 = time.time() - world.t
        for name in self.arms:
            self._publish_js(name, world.t)
            self._publish_slow(name, world.t)
            self.published[name] = 0
        self._publish_states(world.t, every=True)
        if self.tracker is not None:
            self._publish_mocap()
        t_start = world.t
        self._epoch0 = time.time() - t_start
        perf0 = time.perf_counter() - t_start
        wall0 = time.perf_counter()
        if on_ready is not None:
            on_ready()
        period = world.dt
        k = 0
        while not self.stop.is_set():
            if duration is not None and world.t - t_start >= duration - 1e-9:
                break
            self._apply_commands(perf0 + world.t + period)
            self.operator.operator.hold_touch()
            self.clock.tick()
            t = world.t
            for cell in self.cells:
                cell.update()
            for state in self.states.values():
                state.step(t)
            for name in self.arms:
                self._publish_js(name, t)
            k += 1
            self._publish_states(t, every=k % self.state_every == 0)
            if k % self.cp_every == 0:
                for name in self.arms:
                    self._publish_slow(name, t)
            if k % self._refresh_every == 0:
                self._refresh_watched()
            if self.tracker is not None:
                self._publish_mocap()
            if self.natnet is not None:
                self.natnet.pump(self._epoch0)  # Motive's clock is the stamps' timeline
            lag = time.perf_counter() - (perf0 + t)
            if lag > self.max_lag:
                self.max_lag = lag
            if lag < 0:
                time.sleep(-lag)
            else:
                self.late_ticks += 1
                if lag > REANCHOR:
                    # Far behind (the process was stopped, or a debugger held it): re-anchor
                    # instead of bursting to catch up. Shorter stalls (the CPU shared with
                    # other programs) are caught up step by step, so that the commands
                    # received meanwhile act at the steps of their arrival
                    # (`_apply_commands`): a re-anchor applies them all at once, and the
                    # arm's PID sees the set-point jump.
                    perf0 += lag
                    self._epoch0 += lag
                    self.slips += 1
        wall = time.perf_counter() - wall0
        sim = world.t - t_start
        return {"wall_s": wall, "sim_s": sim, "ticks": k,
                "measured_js_hz": {n: c / wall if wall > 0 else 0.0 for n, c in self.published.items()},
                "late_ticks": self.late_ticks, "slips": self.slips, "command_errors": self.command_errors,
                "superseded": self.superseded, "max_lag_s": self.max_lag,
                "dropped": {n: st.dropped for n, st in self.states.items()}}

    def close(self) -> None:
        self.stop.set()
        self._executor.shutdown(timeout_sec=1.0)
        if self._spin_thread.is_alive():
            self._spin_thread.join(timeout=1.0)


def served_config(cfg):
    """`cfg` with every arm simulated: `rig sim` stands in for the arms whatever driver the
    file gives them, so the lab's own rig.toml (ROS arms, a serial load cell, ROS mocap)
    describes what it serves and what the procedures open."""
    arms = {n: dict(a, driver="sim") for n, a in cfg.arms.items()}
    return dataclasses.replace(cfg, arms=arms, loadcell=dict(cfg.loadcell), mocap=dict(cfg.mocap))


def _link_port(path: str, pty: str) -> str | None:
    """Make the configured serial port `path` a symlink to the served pty, so the same
    rig.toml opens it. Only where nothing is, or a link to a pty is (an earlier rig sim):
    a real device is never replaced. Returns the link made, or None."""
    p = Path(path)
    if p.is_symlink():
        if not os.readlink(p).startswith("/dev/pts/"):
            return None
        p.unlink()
    elif p.exists() or not p.parent.is_dir():
        return None
    p.symlink_to(pty)
    return str(p)


@click.command(name="sim")
@click.option("--arms", default=None, help="Comma-separated arms to serve (default: every arm of the configuration, e.g. PSM1,PSM2).")
@click.option("--duration", type=float, default=None, help="Stop after this many seconds (default: until Ctrl-C or SIGTERM).")
@click.option("--rate", type=float, default=None,
              help="Rig (servo) and measured_js rate, Hz (default: the configuration's [rig] rate, 1000).")
@click.option("--cp-rate", type=float, default=100.0, show_default=True,
              help="Rate of setpoint_js, measured_cp, local/measured_cp and body/measured_cf, Hz.")
@click.option("--seed", type=int, default=None, help="Seed of the simulated rig (default: the configuration's).")
@click.option("--loadcell-pty/--no-loadcell", "loadcell", default=True, show_default=True,
              help="Serve a load cell (firmware fake) per object element on a pseudo-terminal and print the paths; "
                   "the configured [loadcell] port, if free, becomes a link to the first.")
@click.option("--mocap/--no-mocap", default=True, show_default=True, help="Publish mocap rigid-body poses.")
@click.option("--natnet/--no-natnet", default=None,
              help="Serve mocap as OptiTrack Motive's NatNet stream on [mocap] server (a loopback address), "
                   "command_port and data_port (multicast to [mocap] multicast if set) (default: when [mocap] "
                   "driver = 'natnet').")
@click.option("--natnet-version", default="4.1", show_default=True, type=click.Choice(["3.0", "3.1", "4.0", "4.1"]),
              help="NatNet bitstream version the fake Motive streams (3.x: Motive 2.x, 4.x: Motive 3.x).")
@click.option("--console", "console", type=click.Choice(["/console", "/system"]), default=None,
              help="Namespace of the console topics (power_on, power_off, home): /console as dVRK 2.3, /system as "
                   "dVRK 2.4 (default: the configuration's [ros] console, else /console).")
@click.option("--plant-model", type=click.Path(dir_okay=False), default=None,
              help="Model file (model.json of `rig identify` or `rig discrepancy`) the served arms' plants take: "
                   "its parameters and added effects (default: each arm's plant_model, else the nominal PSM).")
@click.option("--steps", "list_steps", is_flag=True, help="List the steps and exit.")
@click.pass_context
def command(ctx, arms, duration, rate, cp_rate, seed, loadcell, mocap, natnet, natnet_version, console, plant_model,
            list_steps):
    """Serve the simulated rig as the dVRK's ROS 2 topics (/<ARM>/measured_js ... at RATE Hz),
    mocap poses on /mocap/<body>/pose and the load cell on a pty, paced to the wall clock.

    Every arm of the configuration is served, whatever its driver, so one rig.toml (ROS
    arms, a serial load cell, ROS mocap, [operator] driver = "ros") serves here and drives
    the procedures in another process. The manual steps of a procedure (take the object
    off, attach it, hang masses on the load cell, touch a point) are done by the
    simulation when asked on /rig_sim/operator/request.

    Prints 'loadcell: <pty>' and then 'ready' when serving; prints the achieved
    measured_js rate at exit. Use ROS_DOMAIN_ID and ROS_AUTOMATIC_DISCOVERY_RANGE to choose
    who sees it.
    """
    if list_steps:
        for i, s in enumerate(STEPS, 1):
            _say(f"{i}. {s}")
        return
    from rig.run import config_from_context
    from rig.sim import world_from_config

    cfg = served_config(config_from_context(ctx))
    rate = cfg.rig["rate"] if rate is None else rate
    if rate <= 0 or cp_rate <= 0:
        raise click.BadParameter("rates must be > 0 Hz")
    cfg = dataclasses.replace(cfg, rig=dict(cfg.rig, rate=float(rate)))
    names = [a.strip() for a in arms.split(",")] if arms else list(cfg.arms)
    for n in names:
        if n not in cfg.arms:
            raise click.BadParameter(f"no arm {n!r} in {cfg.source}; arms: {', '.join(cfg.arms)}",
                                     param_hint="--arms")
    if plant_model:
        from rig.config import ConfigError, with_plant_model

        try:
            cfg = with_plant_model(cfg, plant_model, names)
        except ConfigError as exc:
            raise click.BadParameter(str(exc), param_hint="--plant-model") from None
    if console is None:
        console = cfg.ros["console"] if cfg.ros["console"] != "auto" else "/console"
    if natnet is None:
        natnet = cfg.mocap["driver"] == "natnet"
    natnet_host = None
    if natnet:
        import socket as _socket

        from drivers.natnet_server import check_loopback

        try:
            natnet_host = check_loopback(_socket.gethostbyname(cfg.mocap["server"]))
        except (ValueError, OSError):
            raise click.BadParameter(f"the fake Motive serves on this machine's loopback only, and [mocap] server in "
                                     f"{cfg.source} is {cfg.mocap['server']!r}: set it to '127.0.0.1'",
                                     param_hint="--natnet") from None
    world = world_from_config(cfg, arms=names, seed=seed)

    stop = threading.Event()

    def on_signal(signum, _frame):
        stop.set()

    from drivers.operator_sim import CellLoad

    firmwares, cells, links = [], [], []
    if loadcell and cfg.loadcell["driver"] != "none" and world.object is not None:
        from drivers.loadcell_process import FirmwareProcess

        first = min(cfg.loadcell["element"], len(world.object_elements) - 1)
        order = [first] + [k for k in range(len(world.object_elements)) if k != first]
        for k in order:
            # each "Arduino" in its own process: its samples keep their pace whatever this
            # loop is doing (see drivers.loadcell_process)
            fw = FirmwareProcess(noise=cfg.loadcell["noise"], rate_hz=int(round(cfg.loadcell["rate"])),
                                 seed=world.seed + 7 * k)
            firmwares.append(fw)
            cell = CellLoad(world, k, sink=fw.set_tension, cable=fw.unplug)
            cell.update()
            cells.append(cell)
            a, b = world.object_elements[k]
            _say(f"loadcell: {fw.port_path}" if k == first else f"loadcell {a}-{b}: {fw.port_path}")
        # the configured ports (one, or one per element) become links to the served ptys
        wanted = ({k: port for k, port in enumerate(cfg.loadcell["ports"])} if cfg.loadcell["ports"]
                  else {first: cfg.loadcell["port"]} if cfg.loadcell["port"] else {})
        if cfg.loadcell["driver"] == "serial":
            for k, port in wanted.items():
                if k >= len(order):
                    continue
                pty = firmwares[order.index(k)].port_path
                link = _link_port(port, pty)
                if link:
                    links.append(link)
                    _say(f"loadcell link: {link} -> {pty}")

    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions

    context = Context()
    # Our own handlers stop the loop cleanly; rclpy's would shut the context under it.
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    node = server = None
    try:
        node = rclpy.create_node("rig_sim", context=context)
        mocap_cfg = dict(cfg.mocap) if mocap and cfg.mocap["driver"] != "none" else None
        server = SimServer(world, node, list(world.names), cp_rate=cp_rate, mocap=mocap_cfg, seed=world.seed,
                           console=console, cells=cells, executor=cfg.ros["executor"])
        server.stop = stop
        if natnet:
            from drivers.natnet_server import SimMotive, parse_version

            m = cfg.mocap
            try:
                # Motive's clock counts from before its first frame, as a PC's counter does
                server.natnet = SimMotive(world, server.clock, noise=m["noise"], latency=m["latency"],
                                          occlusion=m["occlusion"], rate=m["rate"], seed=world.seed + 1,
                                          host=natnet_host, command_port=m["command_port"], data_port=m["data_port"],
                                          multicast=m["multicast"], version=parse_version(natnet_version),
                                          epoch=time.time() - 3600.0).start()
            except OSError as exc:
                raise click.ClickException(
                    f"cannot serve NatNet on {natnet_host}:{m['command_port']} (data {m['data_port']}): "
                    f"{exc.strerror or exc}; another Motive or `rig sim --natnet` serves there: stop it, or set "
                    f"[mocap] command_port and data_port in {cfg.source}") from None
            _say(f"natnet: {natnet_host}:{m['command_port']} (data {m['data_port']}, "
                 f"{'multicast ' + m['multicast'] if m['multicast'] else 'unicast'}, NatNet {natnet_version}, "
                 f"{m['rate']:g} Hz)")
        # Installed after rclpy is up: its initialisation replaces SIGINT/SIGTERM handlers.
        signal.signal(signal.SIGINT, on_signal)
        signal.signal(signal.SIGTERM, on_signal)
        print(f"rig sim: serving {', '.join(world.names)} at {rate:g} Hz on ROS_DOMAIN_ID="
              f"{os.environ.get('ROS_DOMAIN_ID', '0')}, console {console}, operator on /rig_sim/operator",
              file=sys.stderr, flush=True)
        stats = server.serve(duration, on_ready=lambda: _say("ready"))
    finally:
        if server is not None:
            server.close()
            if server.natnet is not None:
                server.natnet.close()
        for fw in firmwares:
            fw.close()
        for link in links:
            try:
                os.unlink(link)
            except OSError:
                pass
        if node is not None:
            node.destroy_node()
        rclpy.shutdown(context=context)
    hz = stats["measured_js_hz"]
    rates = ", ".join(f"{n} {v:.1f} Hz" for n, v in hz.items())
    held = all(v >= 0.98 * rate for v in hz.values())
    _say(f"measured_js achieved: {rates} (target {rate:g} Hz{'' if held else ', NOT held'}); "
         f"{stats['sim_s']:.3f} s simulated in {stats['wall_s']:.3f} s wall; late ticks {stats['late_ticks']} (longest "
         f"{stats['max_lag_s'] * 1e3:.1f} ms behind), "
         f"re-anchored {stats['slips']}, refused commands {stats['command_errors']}, superseded "
         f"{stats['superseded']}, dropped (arm not ready) {sum(stats['dropped'].values())}, "
         f"operator requests {sum(server.operator.served.values())}")

"""`rig sim`: serve the simulated rig over the real device protocols, like the dVRK's
simulation mode.

One process, paced to the wall clock:

* every simulated arm as the dVRK 2.3 CRTK topics under /<arm>: measured_js at the rig
  rate (default 1 kHz); setpoint_js, measured_cp, local/measured_cp and body/measured_cf
  at `--cp-rate` (default 100 Hz, the dVRK ROS bridge's default publishing rate, which
  also keeps the CPU budget for the 1 kHz stream); servo_jp, servo_jf and move_jp are
  subscribed and drive `drivers.sim_arm.SimArm` (the same fake the in-process tests use,
  trajectory generator included); /console/power_on, /console/power_off and
  /console/home act on every arm (home: move_jp to the arm's q0);
* the mocap system as geometry_msgs/PoseStamped on /<prefix>/<body>/pose at the mocap
  rate (default 120 Hz) from `drivers.mocap_sim.SimTracker` (noise, occlusion, latency;
  quaternions on the wire are geometry_msgs' (x, y, z, w)); an occluded body is simply not
  published in that frame, as mocap bridges do;
* the load cell: `drivers.loadcell.FakeLoadCellFirmware` on a pseudo-terminal fed by the
  world's tension (printed as `loadcell: /dev/pts/N`; open it with pyserial).

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
                 seed: int = 0, console: str = "/console", cells: list | None = None):
        from geometry_msgs.msg import PoseStamped, WrenchStamped
        from rclpy.qos import QoSProfile
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Empty

        from drivers.crtk import PSM_JOINT_NAMES
        from drivers.mocap_sim import SimTracker
        from rig.clock import SimClock
        from drivers.sim_arm import SimArm

        self.world = world
        world.pace = False
        self.node = node
        self.clock = SimClock(world)
        self.arms = {n: SimArm(world, n, self.clock) for n in arms}
        self.rate = self.clock.rate
        self.cp_every = max(1, int(round(self.rate / cp_rate)))
        self._commands: deque = deque()
        self._Msg = {"js": JointState, "pose": PoseStamped, "wrench": WrenchStamped}
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
            arm = self.arms[n]
            node.create_subscription(JointState, f"{ns}/servo_jp", self._queued(self._servo_jp, arm), qos)
            node.create_subscription(JointState, f"{ns}/servo_jf", self._queued(self._servo_jf, arm), qos)
            node.create_subscription(JointState, f"{ns}/move_jp", self._queued(self._move_jp, arm), qos)
        self.console = "/" + console.strip("/")
        for what in ("power_on", "power_off", "home"):
            node.create_subscription(Empty, f"{self.console}/{what}", self._queued(self._console, what), qos)
        from drivers.operator_sim import OperatorServer, SimOperator

        # the operator's side channel: what a person does by hand, done by the simulation
        self.operator = OperatorServer(SimOperator(world, self.arms, cell=(cells or [None])[0]), node)
        self.tracker = None
        if mocap is not None:
            from drivers.mocap import pose_topic

            self.tracker = SimTracker(world, self.clock, noise=mocap["noise"], latency=mocap["latency"],
                                      occlusion=mocap["occlusion"], rate=mocap["rate"],
                                      quaternion_order="xyzw", seed=seed + 1)
            self._mocap_pub = {b: node.create_publisher(PoseStamped, pose_topic(mocap["prefix"], b), qos)
                               for b in self.tracker.bodies}
        self.published = {n: 0 for n in arms}
        self.command_errors = 0
        self.late_ticks = 0
        self.slips = 0
        self.stop = threading.Event()
        from rclpy.executors import SingleThreadedExecutor

        self._executor = SingleThreadedExecutor(context=node.context)
        self._executor.add_node(node)
        self._spin_thread = threading.Thread(target=self._spin, name="sim-executor", daemon=True)

    # -- subscriptions (executor thread): queue, never touch the world -----------------
    def _spin(self) -> None:
        try:
            self._executor.spin()
        except Exception:  # noqa: BLE001 - the context was shut down while stopping
            if not self.stop.is_set():
                raise

    def _queued(self, fn, arg):
        def callback(msg) -> None:
            self._commands.append((fn, arg, msg))
        return callback

    @staticmethod
    def _servo_jp(arm, m) -> None:
        arm.servo_jp(m.position, m.velocity if len(m.velocity) >= 3 else None)

    @staticmethod
    def _servo_jf(arm, m) -> None:
        arm.servo_jf(m.effort)

    @staticmethod
    def _move_jp(arm, m) -> None:
        arm.move_jp(m.position, wait=False)

    def _console(self, what, _msg) -> None:
        for arm in self.arms.values():
            if what == "power_on":
                arm.power_on()
            elif what == "power_off":
                arm.power_off()
            else:
                arm.home(wait=False)

    def _apply_commands(self) -> None:
        self.operator.apply()
        while self._commands:
            fn, arg, msg = self._commands.popleft()
            try:
                fn(arg, msg)
            except ValueError as exc:  # a malformed command is refused, reported, counted
                self.command_errors += 1
                self.node.get_logger().warning(f"command refused: {exc}")

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

    def _publish_slow(self, name: str, t: float) -> None:
        from drivers.quaternion import matrix_to_quat_xyzw

        arm, pub, Msg = self.arms[name], self._pub[name], self._Msg
        sp = arm.setpoint_js()
        m = Msg["js"]()
        m.name = list(arm.joint_names)
        m.header.frame_id = name
        self._stamp(m, t)
        m.position, m.velocity, m.effort = sp.position.tolist(), sp.velocity.tolist(), sp.effort.tolist()
        pub["setpoint_js"].publish(m)
        cp = arm.measured_cp()
        pm = Msg["pose"]()
        self._stamp(pm, t)
        pm.header.frame_id = cp.frame
        pm.pose.position.x, pm.pose.position.y, pm.pose.position.z = cp.position.tolist()
        o = pm.pose.orientation
        o.x, o.y, o.z, o.w = matrix_to_quat_xyzw(cp.rotation).tolist()  # geometry_msgs order
        pub["measured_cp"].publish(pm)
        pub["local/measured_cp"].publish(pm)  # no base frame on a simulated PSM: the same pose
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
                pm = self._Msg["pose"]()
                self._stamp(pm, frame.t)
                pm.header.frame_id = "world"
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
            self._apply_commands()
            self.clock.tick()
            t = world.t
            for name in self.arms:
                self._publish_js(name, t)
            k += 1
            if k % self.cp_every == 0:
                for name in self.arms:
                    self._publish_slow(name, t)
            if self.tracker is not None:
                self._publish_mocap()
            lag = time.perf_counter() - (perf0 + t)
            if lag < 0:
                time.sleep(-lag)
            else:
                self.late_ticks += 1
                if lag > 50 * period:
                    # Far behind (a stall): re-anchor instead of bursting to catch up.
                    perf0 += lag
                    self._epoch0 += lag
                    self.slips += 1
        wall = time.perf_counter() - wall0
        sim = world.t - t_start
        return {"wall_s": wall, "sim_s": sim, "ticks": k,
                "measured_js_hz": {n: c / wall if wall > 0 else 0.0 for n, c in self.published.items()},
                "late_ticks": self.late_ticks, "slips": self.slips, "command_errors": self.command_errors}

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
@click.option("--console", "console", type=click.Choice(["/console", "/system"]), default=None,
              help="Namespace of the console topics (power_on, power_off, home): /console as dVRK 2.3, /system as "
                   "dVRK 2.4 (default: the configuration's [ros] console, else /console).")
@click.option("--plant-model", type=click.Path(dir_okay=False), default=None,
              help="Model file (model.json of `rig identify` or `rig discrepancy`) the served arms' plants take: "
                   "its parameters and added effects (default: each arm's plant_model, else the nominal PSM).")
@click.option("--steps", "list_steps", is_flag=True, help="List the steps and exit.")
@click.pass_context
def command(ctx, arms, duration, rate, cp_rate, seed, loadcell, mocap, console, plant_model, list_steps):
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
    world = world_from_config(cfg, arms=names, seed=seed)

    stop = threading.Event()

    def on_signal(signum, _frame):
        stop.set()

    from drivers.operator_sim import CellLoad

    firmwares, cells, links = [], [], []
    if loadcell and cfg.loadcell["driver"] != "none" and world.object is not None:
        from drivers.loadcell import FakeLoadCellFirmware

        first = min(cfg.loadcell["element"], len(world.object_elements) - 1)
        order = [first] + [k for k in range(len(world.object_elements)) if k != first]
        for k in order:
            cell = CellLoad(world, k)
            fw = FakeLoadCellFirmware(cell, noise=cfg.loadcell["noise"], rate_hz=int(round(cfg.loadcell["rate"])),
                                      seed=world.seed + 7 * k)
            fw.start()
            firmwares.append(fw)
            cells.append(cell)
            a, b = world.object_elements[k]
            _say(f"loadcell: {fw.port_path}" if k == first else f"loadcell {a}-{b}: {fw.port_path}")
        if cfg.loadcell["driver"] == "serial" and cfg.loadcell["port"]:
            link = _link_port(cfg.loadcell["port"], firmwares[0].port_path)
            if link:
                links.append(link)
                _say(f"loadcell link: {link} -> {firmwares[0].port_path}")

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
                           console=console, cells=cells)
        server.stop = stop
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
         f"{stats['sim_s']:.3f} s simulated in {stats['wall_s']:.3f} s wall; late ticks {stats['late_ticks']}, "
         f"re-anchored {stats['slips']}, refused commands {stats['command_errors']}, "
         f"operator requests {sum(server.operator.served.values())}")

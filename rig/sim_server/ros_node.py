"""The simulated rig served over ROS 2 as whole dVRK PSMs, mocap poses and the operator's channel.

`SimServer` is what `rig sim` runs, in one process, paced to the wall clock:

* every simulated arm as a whole dVRK 2.4 PSM (`drivers.arm.fake_psm.FakePSM` behind its
  operating state `drivers.arm.fake_arm_state.FakeArmState`) on the CRTK topics of
  `rig.sim_server.crtk_bridge.ArmBridge`: the streams every ROS period (`ros_period`, as
  `dvrk_system -p`), each only while it has a subscriber (looked up at 10 Hz, and at once
  from the publisher's matched event), written straight to CDR bytes, the events (operating_state, error, warning, status, goal_reached, the
  trajectory ratio) when they happen;
* the console under `console` (/console as dVRK 2.3, /system as 2.4): power_on,
  power_off and home act on every arm through its state machine; set_volume, beep and
  string_to_speech are accepted and logged; /console/teleop/... (enable, set_scale,
  select, unselect; scale, selected, unselected published latched) as the dVRK's console;
* the mocap system as geometry_msgs/PoseStamped on /<prefix>/<body>/pose at the mocap
  rate, while any body's topic has a subscriber (`drivers.mocap.fake_ros_mocap.FakeRosMocap`:
  noise, occlusion, latency; an occluded body is not published in that frame);
* the operator's side channel (`drivers.operator.fake_operator_server.FakeOperatorServer`): the manual steps
  of a procedure done by the simulation, and the faults a test injects.

Threads: the main thread applies the received commands, runs each arm's servo loop
(`FakePSM.control`), steps the world and the wrists, publishes and paces (sleeps to
`start + k / rate`); an executor thread spins the node, whose subscriptions only queue
(the world has one writer) and whose services answer from kinematics alone. Stream
stamps are `wall time at start + simulated time`; event stamps are the wall time when
published, strictly increasing, so that a client sees every event as newer than the one
before (crtk's client keeps only a newer operating_state).
"""

from __future__ import annotations

import threading
import time
from collections import deque

#: s behind the wall clock beyond which the served rig re-anchors its time instead of catching up
REANCHOR = 0.05
#: s, the dVRK console's default ROS publishing period (`dvrk_system -p 0.01`)
DVRK_ROS_PERIOD = 0.01
#: ns: a command stamped older than an arm's last one by less than this was overtaken on
#: the wire (superseded); by more, it comes from another clock
REORDER_NS = 1_000_000_000


class SimServer:
    """The simulated rig served on a ROS 2 node (see the module docstring).

    world: a `rig.sim.world.SimWorld` (its own pacing is turned off: the server paces); node: an
    rclpy Node, spun here on an executor thread; arms: names to serve; ros_period: s
    between two publications of the arm streams; mocap: a dict with prefix, rate, noise,
    latency, occlusion (or None for no mocap); console: "/console" or "/system"; cells:
    the `CellLoad`s of the served load cells, the configured one first; object_spec: what
    the operator attaches (the world may start without it); tool: the PSMs' tool name.
    """

    def __init__(self, world, node, arms: list[str], ros_period: float = DVRK_ROS_PERIOD,
                 mocap: dict | None = None, seed: int = 0, console: str = "/console", cells: list | None = None,
                 executor: str = "events", object_spec=None, tool: str | None = None, sim_time: bool = False,
                 lockstep: bool = True, lockstep_timeout: float = 3.0, servo_ci: bool = True):
        from rclpy.qos import DurabilityPolicy, QoSProfile
        from std_msgs.msg import Bool, Empty, Float64, Float64MultiArray, String

        from drivers.operator.fake_operator_server import FakeOperatorServer
        from drivers.operator.sim import SimOperator
        from drivers.arm.sim import SimArm
        from drivers.arm.fake_arm_state import FakeArmState
        from drivers.arm.fake_psm import FakePSM
        from rig.devices.clock import SimClock
        from rig.sim_server.crtk_bridge import ArmBridge
        from rig.model.psm_tool import tool as tool_named

        self.world = world
        world.pace = False
        self.node = node
        self.clock = SimClock(world)
        the_tool = tool_named(tool) if tool else None
        # SimArm: the operator's hands on joints 1-3 (a touch holds a tip); FakePSM: the arm
        self.sim_arms = {n: SimArm(world, n, self.clock) for n in arms}
        self.psms = {n: FakePSM(world, n, self.clock, tool=the_tool) for n in arms}
        self.states = {n: FakeArmState(self.psms[n]) for n in arms}
        self.rate = self.clock.rate
        self.ros_period = float(ros_period)
        self.ros_every = max(1, int(round(self.ros_period * self.rate)))
        self._refresh_every = max(1, int(round(0.1 * self.rate)))  # subscribers looked up at 10 Hz
        # A stream is built only while it has a subscriber, at every period: a client that
        # subscribes late is seen at once (each publisher's matched event) and gets its
        # first sample at the next period, as from a dVRK that publishes to everyone
        self._commands: deque = deque()
        self._last_event = 0
        qos = QoSProfile(depth=10)
        self.bridges = {n: ArmBridge(node, self.psms[n], self.states[n], self._queued, self._stamp_ns,
                                     self._event_stamp_ns, servo_ci=servo_ci) for n in arms}
        for b in self.bridges.values():
            b.publish_initial()
        self.console = "/" + console.strip("/")
        #: --sim-time: stamps and /clock on the world's time; lockstep: the world waits for the
        #: processes that follow its clock (rig.sim_server.lockstep)
        self.sim_time = bool(sim_time)
        self.lockstep = None
        self._clock_pub = self._clock_msg = None
        if self.sim_time:
            from rosgraph_msgs.msg import Clock

            self._clock_pub = node.create_publisher(Clock, "/clock", QoSProfile(depth=10))
            self._clock_msg = Clock()
            if lockstep:
                from rig.sim_server.lockstep import Lockstep

                self.lockstep = Lockstep(node, timeout=lockstep_timeout, log=node.get_logger().info,
                                         repeat=self._repeat_clock)
        self._clock_lock = threading.Lock()
        self._clock_at: float | None = None  # monotonic s of the last /clock published (None: none yet)
        #: on simulated time, repeats the newest /clock while the world's loop is held up
        #: anywhere (`_repeat_while_held`)
        self._repeater = threading.Thread(target=self._repeat_while_held, name="sim-clock-repeat", daemon=True)
        self._subs = []
        for what in ("power_on", "power_off", "home"):
            self._subs.append(node.create_subscription(Empty, f"{self.console}/{what}",
                                                       self._queued(self._console, what), qos))
        self.console_log: list[str] = []
        for what, msg_type in (("set_volume", Float64), ("beep", Float64MultiArray), ("string_to_speech", String)):
            self._subs.append(node.create_subscription(msg_type, f"{self.console}/{what}",
                                                       lambda m, what=what: self._console_said(what, m), qos))
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.teleop = {"scale": 0.2, "enabled": False, "selected": set()}
        self._teleop_pub = {k: node.create_publisher(t, f"/console/teleop/{k}", latched)
                            for k, t in (("scale", Float64), ("selected", String), ("unselected", String))}
        for what, msg_type in (("enable", Bool), ("set_scale", Float64), ("select", String), ("unselect", String)):
            self._subs.append(node.create_subscription(msg_type, f"/console/teleop/{what}",
                                                       lambda m, what=what: self._teleop(what, m), qos))
        self._teleop_pub["scale"].publish(Float64(data=self.teleop["scale"]))
        self._String = String
        self.operator = FakeOperatorServer(SimOperator(world, self.sim_arms, cell=(cells or [None])[0],
                                                       cells={c.element: c for c in cells or []},
                                                       states=self.states, object_spec=object_spec), node)
        self.cells = list(cells or [])
        self.operator.operator.cables["mocap"] = self._unplug_mocap
        self.mocap_unplugged = False
        self.natnet = None  # a drivers.natnet.fake_motive.FakeMotiveOnWorld when serving NatNet (`--natnet`)
        self.mocap = None  # the ROS poses: a drivers.mocap.fake_ros_mocap.FakeRosMocap
        if mocap is not None:
            from drivers.mocap.fake_ros_mocap import FakeRosMocap

            self.mocap = FakeRosMocap(world, self.clock, node, prefix=mocap["prefix"], noise=mocap["noise"],
                                      latency=mocap["latency"], occlusion=mocap["occlusion"], rate=mocap["rate"],
                                      seed=seed + 1, qos=qos)
        self._refresh_watched()
        self.command_errors = 0
        self.state_commands = 0
        self.superseded = 0
        self.max_lag = 0.0  # s, the longest the loop fell behind the wall clock
        self._last_command: dict[str, int] = {}
        self.late_ticks = 0
        self.slips = 0
        self.stop = threading.Event()
        self._epoch0 = time.time() - world.t
        from drivers.common.ros_session import make_executor

        self._executor = make_executor(executor, node.context)
        self._executor.add_node(node)
        self._spin_thread = threading.Thread(target=self._spin, name="sim-executor", daemon=True)

    @property
    def published(self) -> dict[str, int]:
        return {n: b.published for n, b in self.bridges.items()}

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
            if self.lockstep is not None:
                self.lockstep.command_received()
        return callback

    def _console(self, what, _msg) -> bool:
        # the console's buttons act on every arm, through each arm's state machine
        command = {"power_on": "enable", "power_off": "disable", "home": "home"}[what]
        for state in self.states.values():
            state.command(command, self.world.t)
        return False

    def _console_said(self, what: str, m) -> None:
        """beep, set_volume, string_to_speech: accepted and logged (a simulated console has no speaker)."""
        value = list(m.data) if what == "beep" else m.data
        text = f"{self.console}/{what}: {value}"
        self.console_log.append(text)
        self.node.get_logger().info(text)

    def _teleop(self, what: str, m) -> None:
        """The console's teleoperation topics: no MTM here, so nothing moves; the state is
        kept and echoed as the dVRK's console does."""
        from std_msgs.msg import Float64

        if what == "set_scale":
            self.teleop["scale"] = float(m.data)
            self._teleop_pub["scale"].publish(Float64(data=float(m.data)))
        elif what == "enable":
            self.teleop["enabled"] = bool(m.data)
        elif what in ("select", "unselect"):
            (self.teleop["selected"].add if what == "select" else self.teleop["selected"].discard)(str(m.data))
            self._teleop_pub["selected" if what == "select" else "unselected"].publish(self._String(data=str(m.data)))
        self.node.get_logger().info(f"/console/teleop/{what}: {m.data} (no MTM on the simulated rig)")

    def _apply_commands(self, until: float = float("inf")) -> None:
        """Apply the commands received up to perf_counter time `until`: the wall time the
        next step stands for. When the loop runs behind and catches up step by step, each
        command then acts at the step of its arrival, as on an arm that never fell behind,
        instead of the newest of a burst jumping the set-point forward."""
        from rig.sim_server.crtk_bridge import MOTION

        self.operator.apply()
        commands = self._commands
        while commands and commands[0][0] <= until:
            _, fn, key, msg = commands.popleft()
            bridge = getattr(fn, "__self__", None)
            if not hasattr(bridge, "psm"):
                bridge = None  # the console's buttons
            if key in MOTION and bridge is not None:
                # DDS keeps order within a topic only: a servo command sent before a move_jp
                # (a hold) may arrive after it and would cancel the move. One client stamps
                # its commands on one clock, so a command older than the arm's last one is
                # superseded: dropped and counted. One older by more than REORDER comes from
                # another clock (a client of a simulated clock that started over): taken.
                header = getattr(msg, "header", None)
                stamp = 0 if header is None else header.stamp.sec * 1_000_000_000 + header.stamp.nanosec
                last = self._last_command.get(bridge.name, 0)
                if stamp and last - REORDER_NS < stamp < last:
                    self.superseded += 1
                    continue
                if stamp:
                    self._last_command[bridge.name] = stamp
            if key == "state_command":
                self.state_commands += 1
            try:
                obeyed = fn(key, msg)
            except ValueError as exc:  # a malformed command is refused, reported, counted
                self.command_errors += 1
                self.node.get_logger().warning(f"command refused: {exc}")
                continue
            if obeyed and bridge is not None:
                self.operator.operator.release(bridge.name)  # the client takes the arm over

    # -- publishing (main thread) ---------------------------------------------------------
    def _stamp_ns(self, t: float) -> int:
        """The header stamp, in ns, of a stream sample at world time `t` s (on simulated
        time the world's time itself, as /clock says it)."""
        return int(round((t if self.sim_time else self._epoch0 + t) * 1e9))

    def _event_stamp_ns(self) -> int:
        """The header stamp, in ns, of an event published now (strictly increasing)."""
        now = self._stamp_ns(self.world.t) if self.sim_time else time.time_ns()
        ns = max(now, self._last_event + 1000)
        self._last_event = ns
        return ns

    def _refresh_watched(self) -> None:
        """Which streams have subscribers; start or stop the mocap system to match."""
        for b in self.bridges.values():
            b.refresh_watched()
        if self.mocap is not None:
            self.mocap.refresh_watched()

    def _unplug_mocap(self) -> None:
        """The tracker's cable pulled (a fault for tests): no pose is published from now on."""
        self.mocap_unplugged = True
        if self.mocap is not None:
            self.mocap.unplug()

    def _publish_clock(self, t: float) -> None:
        """/clock at world time `t` (rosgraph_msgs/Clock), after the period's streams."""
        ns = self._stamp_ns(t)
        with self._clock_lock:
            self._clock_msg.clock.sec, self._clock_msg.clock.nanosec = divmod(ns, 1_000_000_000)
            self._clock_pub.publish(self._clock_msg)
            self._clock_at = time.monotonic()

    def _repeat_clock(self) -> None:
        """Publish the newest /clock again (the same stamp: time does not move)."""
        with self._clock_lock:
            if self._clock_at is not None:
                self._clock_pub.publish(self._clock_msg)
                self._clock_at = time.monotonic()

    def _repeat_while_held(self) -> None:
        """Its own thread: the newest /clock again every HEARTBEAT s of wall time while the
        world's loop publishes none, wherever the loop is held up: waiting for its
        followers (`Lockstep.wait` repeats too), or in the kernel. The served load cells'
        pty is read in the loop on simulated time, and on a loaded machine a read of its
        master end was held there 1-3.6 s while a procedure opened the cell's port (probed:
        the world thread in os.read); its followers took the silent simulator for a dead one
        (ClockStopped). A clock repeated tells them it lives, and its time does not move."""
        from drivers.common.time_base import HEARTBEAT

        while not self.stop.wait(HEARTBEAT / 2):
            at = self._clock_at
            if at is not None and time.monotonic() - at > HEARTBEAT:
                self._repeat_clock()

    # -- the loop -------------------------------------------------------------------------
    def _tick(self) -> None:
        """One servo period: each arm's control, the world's step, the wrists' step, the states."""
        t = self.world.t
        for psm in self.psms.values():
            psm.control(t)
        self.clock.tick()
        t = self.world.t
        for psm in self.psms.values():
            psm.step_wrist()
        for cell in self.cells:
            cell.update()
        for state in self.states.values():
            state.step(t)

    def serve(self, duration: float | None = None, on_ready=None) -> dict:
        """Step, publish and pace until `stop` is set or `duration` s of sim time passed."""
        self._spin_thread.start()
        if self.sim_time:
            self._repeater.start()
        world = self.world
        # One untimed tick first: loading the compiled physics kernel and the first
        # publications take a fraction of a second that would count as a stall.
        self._tick()
        self._epoch0 = time.time() - world.t
        for b in self.bridges.values():
            b.publish_streams(world.t)
            b.publish_events()
            b.published = 0
        if self.mocap is not None:
            self.mocap.publish(self._stamp_ns)
        if self.sim_time:
            self._publish_clock(world.t)
        t_start = world.t
        self._epoch0 = time.time() - t_start
        perf0 = time.perf_counter() - t_start
        wall0 = time.perf_counter()
        if on_ready is not None:
            on_ready()
        period = world.dt
        k = 0
        lockstep = self.lockstep
        # the world's pace while procedures follow it (s simulated, s of wall time)
        followed_sim = followed_wall = 0.0
        last_iter = time.perf_counter()
        while not self.stop.is_set():
            if duration is not None and world.t - t_start >= duration - 1e-9:
                break
            if lockstep is not None and k % self.ros_every == 0 and lockstep.active:
                # the period's samples are out: step past it once its followers answered it
                lockstep.wait(self._stamp_ns(world.t), self.stop)
            # on simulated time a command acts at the first step after it came; on the wall
            # clock at the step of the wall time it came at (see _apply_commands)
            self._apply_commands(float("inf") if self.sim_time else perf0 + world.t + period)
            self.operator.operator.hold_touch()
            self._tick()
            t = world.t
            k += 1
            for b in self.bridges.values():
                b.publish_events()
            if k % self.ros_every == 0:
                for b in self.bridges.values():
                    b.publish_streams(t)
                if self.sim_time:
                    self._publish_clock(t)
            if k % self._refresh_every == 0:
                self._refresh_watched()
            if self.mocap is not None:
                self.mocap.publish(self._stamp_ns)
            if self.natnet is not None and not self.mocap_unplugged:
                self.natnet.pump(self._epoch0)  # Motive's clock is the stamps' timeline
            if lockstep is not None and lockstep.active:
                # the world runs as fast as its followers answer: nothing waits for the wall
                # clock (the anchor moves with it, so pacing resumes from here once they leave)
                now = time.perf_counter()
                followed_sim += period
                followed_wall += now - last_iter
                last_iter = now
                perf0 = now - t
                continue
            last_iter = time.perf_counter()
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
                "dropped": {n: st.dropped for n, st in self.states.items()},
                "clock": "simulated" if self.sim_time else "wall", "real_time_factor": sim / wall if wall > 0 else 0.0,
                **({} if self.lockstep is None else {
                    "lockstep": {"lost": self.lockstep.lost, "late_commands": self.lockstep.late_commands,
                                 "waits": self.lockstep.waits, "wait_s": self.lockstep.wait_s,
                                 "followed_sim_s": followed_sim, "followed_wall_s": followed_wall,
                                 "real_time_factor": followed_sim / followed_wall if followed_wall > 0 else 0.0}})}

    def close(self) -> None:
        self.stop.set()
        if self._repeater.is_alive():
            self._repeater.join(timeout=1.0)
        self._executor.shutdown(timeout_sec=1.0)
        if self._spin_thread.is_alive():
            self._spin_thread.join(timeout=1.0)

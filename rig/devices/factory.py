"""The device factory procedures call: `open_rig(cfg) -> Rig` (clock, arms, force sensor, tracker).

This is the one place that decides simulated or real, from the configuration, so no
procedure or driver needs an `if simulated:` branch.

* Simulated arms (driver "sim"): one `SimWorld` from `world_from_config`, a `SimClock`
  stepping it (faster than real time unless `rig.pace`), `SimArm`s, the load cell as
  `SimForceSensor` (the firmware's device model and byte framing on simulated time; see
  `drivers.loadcell.sim` for why not the pty fake) and mocap as `SimTracker`.
* Real arms (driver "ros"): a `StreamClock` at `rig.rate` (each tick waits for a fresh
  measured_js of every arm; with `[ros] use_sim_time`, a `SimTimeClock` on the simulator's
  /clock in lockstep, every driver's waits on it too), one rclpy context and node owned
  by the Rig and spun by one executor thread, `RosArm`s on it (watchdog from each arm's
  config), the serial or CAN `LoadCell` and `RosMocapTracker` on the same node. Opening
  connects (`connect`): it waits for every stream, then enables and homes the arms
  through their operating state (`ready_arms`), as a procedure moves only arms that are
  ENABLED and homed.

Mixing simulated and real arms in one rig is refused: they would live on different clocks.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from drivers.interfaces import Arm, ForceSensor, Operator, Tracker
from rig.config import ConfigError
from rig.devices.clock import Clock, SimClock, SimTimeClock, StreamClock
from rig.faults import DeviceFault

if TYPE_CHECKING:  # imported where a rig is opened: ROS and the world load only when used
    from drivers.common.ros_session import RosSession
    from rig.sim.world import SimWorld


@dataclass
class Rig:
    """What a procedure drives, each device by its interface (drivers.interfaces): a procedure
    calls what the interface promises and probes for nothing. `world` is the simulated
    world (None on the real rig): a procedure reads it for the simulated truth only."""

    clock: Clock
    arms: dict[str, Arm]
    force: ForceSensor | None = None
    # One force sensor per object element, in the world's element order. The simulated rig
    # puts a load cell on every element (three arms hold a triangle); a real rig has the
    # one configured load cell, on element `loadcell.element`.
    forces: dict[int, ForceSensor] = field(default_factory=dict)
    tracker: Tracker | None = None
    world: SimWorld | None = None
    session: RosSession | None = None  # the RosSession of ROS arms
    operator: Operator | None = None  # who does the manual steps (drivers.operator.driver)
    _closers: list = field(default_factory=list, repr=False)

    @property
    def simulated(self) -> bool:
        return self.world is not None

    def close(self) -> None:
        """Close every device, newest first; each in its own try so one failure spares the rest."""
        errors = []
        while self._closers:
            fn = self._closers.pop()
            try:
                fn()
            except Exception as exc:  # noqa: BLE001 - report after closing the others
                errors.append(exc)
        if errors:
            raise errors[0]

    def __enter__(self) -> "Rig":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


#: the devices besides the arms that a procedure may use (`open_rig(uses=...)`)
DEVICES = ("loadcell", "mocap")


class ConnectError(DeviceFault):
    """A device the procedure needs never answered: one line naming the stream and what to check."""


def open_rig(cfg, arms: list[str] | None = None, *, seed: int | None = None,
             uses: tuple[str, ...] = DEVICES, connect_timeout: float | None = None,
             say=None, arm_streams: tuple[str, ...] = ("measured_js",), loop_rate: float | None = None) -> Rig:
    """Open the devices of `cfg` (a `rig.config.RigConfig`); `arms` limits which arms.

    uses: the devices besides the arms the procedure uses ("loadcell", "mocap"); the
    others are not opened (no port taken, no subscription made). On ROS arms the rig
    connects before it returns: it waits up to `connect_timeout` s (default
    `[ros] connect_timeout`) for the first message of every stream and reports what it
    found through `say(line)` (default: stderr); `arm_streams` are the arm topics to
    subscribe besides measured_js. `rig.operator` does the manual steps: the simulation
    on the simulated rig, `rig sim`'s operator with `[operator] driver = "ros"`, else the
    person at the console (`[operator] yes`: every request taken as done, for a prepared rig).
    `loop_rate` (Hz): the lowest arm stream rate the procedure's loop works at (default
    `[rig] rate`); a slower one is refused at connection (`check_stream_rates`).
    """
    unknown = set(uses) - set(DEVICES)
    if unknown:
        raise ValueError(f"unknown devices {sorted(unknown)}; known: {', '.join(DEVICES)}")
    names = list(arms) if arms else list(cfg.arms)
    for n in names:
        if n not in cfg.arms:
            raise ConfigError(f"{cfg.source}: no arm {n!r}; arms: {', '.join(cfg.arms)}")
    drivers = {cfg.arms[n]["driver"] for n in names}
    if len(drivers) > 1:
        raise ConfigError(f"{cfg.source}: arms {names} mix simulated and ROS drivers; "
                         "run `rig sim` to serve the simulated ones over ROS 2 instead")
    if drivers == {"sim"}:
        rig = _open_simulated(cfg, names, seed, uses)
        from drivers.operator.sim import SimOperator

        rig.operator = SimOperator(rig.world, rig.arms)
        if rig.tracker is not None:  # a person can pull the tracker's cable, as in `rig sim`
            rig.operator.cables["mocap"] = rig.tracker.unplug
        return rig
    rig = _open_ros(cfg, names, uses, arm_streams)
    try:
        connect(rig, cfg, names, connect_timeout if connect_timeout is not None else cfg.ros["connect_timeout"],
                say or _stderr, loop_rate)
    except BaseException:
        rig.close()
        raise
    return rig


def _stderr(line: str) -> None:
    import sys

    print(line, file=sys.stderr, flush=True)


def _open_simulated(cfg, names: list[str], seed: int | None, uses) -> Rig:
    from drivers.loadcell.sim import SimForceSensor
    from drivers.mocap.sim import SimTracker
    from rig.sim.world import world_from_config

    from drivers.arm.sim import SimArm

    if "mocap" in uses and cfg.mocap["driver"] == "natnet":
        raise ConfigError(f"{cfg.source}: mocap.driver = 'natnet' needs ROS arms on the wall clock; run `rig sim "
                          "--natnet` and give the arms driver = 'ros' (or use mocap.driver = 'sim' in one process)")
    world = world_from_config(cfg, arms=names, seed=seed)
    clock = SimClock(world)
    rig = Rig(clock=clock, arms={n: SimArm(world, n, clock) for n in names}, world=world)
    lc = cfg.loadcell
    if "loadcell" in uses and lc["driver"] != "none" and world.object is not None:
        for k in range(len(world.object_elements)):
            sensor = SimForceSensor(world, clock, element=k, rate=lc["rate"], noise=lc["noise"],
                                    seed=world.seed + 2 + 7 * k)
            rig.forces[k] = sensor
            rig._closers.append(sensor.close)
        rig.force = rig.forces[min(lc["element"], len(rig.forces) - 1)]
    m = cfg.mocap
    if "mocap" in uses and m["driver"] != "none":
        rig.tracker = SimTracker(world, clock, noise=m["noise"], latency=m["latency"],
                                 occlusion=m["occlusion"], rate=m["rate"], seed=world.seed + 1,
                                 stale_timeout=m["stale_timeout"])
        rig._closers.append(rig.tracker.close)
    return rig


def open_operator(cfg, session=None):
    """The operator of a rig with real (or `rig sim`) devices: `rig sim`'s over ROS 2 when
    `[operator] driver = "ros"` (on `session`'s control node), else the person at the console."""
    from drivers.operator.driver import ConsoleOperator, RosOperator

    if cfg.operator["driver"] == "ros":
        if session is None:
            raise ValueError("the ROS operator needs a ROS session")
        return RosOperator(session.control, timeout=cfg.operator["timeout"], time_base=session.time)
    return ConsoleOperator(yes=cfg.operator["yes"])


def _once_stopped(session, close):
    """`close` of a driver with endpoints on `session`'s node, run only when no executor
    spins that node (never started, or stopped): with the executor thread stuck, the
    endpoints are left to the process's end instead of crashing it."""
    def closer() -> None:
        if session.executor is None or session.stopped:
            close()
    return closer


def check_crtk_messages(cfg, names: list[str]) -> None:
    """Raise ConfigError, one line naming this Python and the fix, when `names` holds a ROS
    arm and the dVRK's CRTK messages do not load here: without them the arms are never
    enabled nor homed, and servo_ci cannot be sent. Procedures that compute long before
    they open the rig (identify's design) call it first."""
    from drivers.common import crtk_messages

    ros = [n for n in names if cfg.arms[n]["driver"] == "ros"]
    if ros and crtk_messages.problem() is not None:
        raise ConfigError(f"the dVRK arms ({', '.join(ros)}) need the CRTK messages: {crtk_messages.problem()}")


def _open_ros(cfg, names: list[str], uses, arm_streams) -> Rig:
    from drivers.arm.dvrk_arm import RosArm
    from drivers.common.ros_session import RosSession

    check_crtk_messages(cfg, names)
    session = RosSession("rig", executor=cfg.ros["executor"])
    rig = Rig(clock=None, arms={})
    rig.session = session
    rig._closers.append(session.close)
    try:
        if cfg.ros["use_sim_time"]:
            from drivers.common.time_base import SimTime

            # every wait, timeout and stream age on the simulator's /clock; the loop's ticks
            # answer its periods (lockstep)
            session.time = SimTime(session.node, lockstep=cfg.ros["lockstep"], polled=session.executor_time)
            rig._closers.append(session.time.close)  # leave the lockstep last, once the arms are held
            rig.clock = SimTimeClock(cfg.rig["rate"], [], session.time, polled=session.executor_time)
        else:
            # every tick acts on a fresh measured_js of every arm (rig.devices.clock.StreamClock)
            rig.clock = StreamClock(cfg.rig["rate"], [])
        for n in names:
            a = cfg.arms[n]
            arm = RosArm(session.node, a["namespace"], watchdog=a["watchdog"], spin=False, setting=f"[arms.{n}] watchdog",
                         console=cfg.ros["console"], streams=arm_streams, polled=session.executor_time,
                         control_node=session.control, time_base=session.time)
            rig.arms[n] = arm
            arm.clock = rig.clock
            rig.clock.add_source(arm)
            rig._closers.append(_once_stopped(session, arm.close))
        m = cfg.mocap
        if "mocap" in uses and m["driver"] == "ros":
            from drivers.mocap.ros_tracker import RosMocapTracker
            from rig.sim.world import default_marker_bodies

            bodies = [mb.name for n in names for mb in default_marker_bodies(n)] + ["world"]
            rig.tracker = RosMocapTracker(session.node, bodies, prefix=m["prefix"], stale_timeout=m["stale_timeout"],
                                          polled=session.executor_time, time_base=session.time)
            rig._closers.append(_once_stopped(session, rig.tracker.close))
        elif "mocap" in uses and m["driver"] == "natnet":
            from drivers.natnet.tracker import open_natnet_tracker
            from rig.sim.world import default_marker_bodies

            # the handshake (server info, model definitions) happens here; frames are awaited in connect()
            bodies = [mb.name for n in names for mb in default_marker_bodies(n)] + ["world"]
            rig.tracker = open_natnet_tracker(m, bodies, timeout=cfg.ros["connect_timeout"])
            rig._closers.append(rig.tracker.close)
        rig.operator = open_operator(cfg, session)
        if rig.arms and getattr(rig.operator, "watch", "absent") is None:
            # a request waiting for rig sim's person ends on the arms' stale stream or FAULT
            # (rig sim killed is seen in the arms' watchdog, not the operator's timeout)
            arms = list(rig.arms.values())
            rig.operator.watch = lambda: [arm.measured_js() for arm in arms]
        session.start()
        # closed first (the closers run newest first): the executor stops before any driver
        # destroys its endpoints on the node it spins (RosSession.stop)
        rig._closers.append(session.stop)
        if session.time.simulated and not session.time.wait_heard(cfg.ros["connect_timeout"]):
            from drivers.common.ros_session import domain_text
            from drivers.common.time_base import CLOCK_TOPIC

            raise ConnectError(f"{CLOCK_TOPIC}: no simulated time within {cfg.ros['connect_timeout']:g} s on "
                               f"{domain_text()}; [ros] use_sim_time = true in {cfg.source} follows `rig sim "
                               "--sim-time`: start it so (or set use_sim_time = false for a console on the wall clock)")
        # the load cells after the session spins: on simulated time their replies come on its clock
        lc = cfg.loadcell
        if "loadcell" in uses:
            if lc["driver"] == "serial" and lc["ports"]:
                # a cell per object element: each with its own calibration
                rig.forces = {k: _open_loadcell(dict(lc, port=port), rig)
                              for k, port in enumerate(lc["ports"])}
                rig.force = rig.forces[min(lc["element"], len(lc["ports"]) - 1)]
            elif lc["driver"] in ("serial", "can"):
                rig.force = _open_loadcell(lc, rig)
                rig.forces = {lc["element"]: rig.force}
            elif lc["driver"] == "sim":
                raise ConfigError(f"{cfg.source}: loadcell.driver = 'sim' needs simulated arms; with ROS arms "
                                 "use 'serial' with the pty that `rig sim` prints (or 'none')")
    except BaseException:
        rig.close()
        raise
    return rig


def connect(rig: Rig, cfg, names: list[str], timeout: float, say, loop_rate: float | None = None) -> dict:
    """Wait for the first message of every stream the rig opened, then report what it found.

    Arms: measured_js; the load cell: a sample; mocap: a pose of every body. Progress is
    reported once a second; a stream that never arrives raises ConnectError naming its
    topic, the ROS domain and what to check. Returns {stream: rate in Hz} measured over a
    short window after the first messages.
    """
    from drivers.common.ros_session import domain_text

    deadline = time.monotonic() + timeout
    shown = time.monotonic()
    waiting = {f"{rig.arms[n].topic['measured_js']}": rig.arms[n] for n in names}
    # an arm is there once it sends measured_js or its operating state (a disabled dVRK
    # may publish no joints before it is enabled: ready_arms then waits for them)
    say(f"connecting on {domain_text()}: waiting for {', '.join(waiting)}"
        + ("" if rig.force is None else
           ", the load cell" if len(rig.forces) <= 1 else f", {len(rig.forces)} load cells")
        + (", mocap" if rig.tracker is not None else "") + f" (up to {timeout:g} s)")
    while True:
        missing = [topic for topic, arm in waiting.items()
                   if arm.stream_age() == float("inf") and arm.operating_state() is None]
        if rig.tracker is not None:
            missing += [rig.tracker.topics[b] for b, n in rig.tracker.stats.received.items() if n == 0]
        if not missing:
            break
        now = time.monotonic()
        if now > deadline:
            first = missing[0]
            more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
            hint = getattr(rig.tracker, "connect_hint", None)
            if hint and first in rig.tracker.topics.values():  # a tracker of its own protocol (NatNet)
                raise ConnectError(f"{first}: no frame within {timeout:g} s{more}; {hint}")
            raise ConnectError(
                f"{first}: no message within {timeout:g} s on {domain_text()}{more}; check that the dVRK "
                "(or `rig sim`) is running and publishing it, and that ROS_DOMAIN_ID and "
                "ROS_AUTOMATIC_DISCOVERY_RANGE match")
        if now - shown >= 1.0:
            shown = now
            say(f"  still waiting for {', '.join(missing[:4])}{' ...' if len(missing) > 4 else ''} "
                f"({deadline - now:.0f} s left)")
        time.sleep(0.01)
    ready_arms(rig, names, timeout, say)
    op_wait = getattr(rig.operator, "wait_for_server", None)
    if op_wait is not None and not op_wait(max(0.0, deadline - time.monotonic())):
        from drivers.operator.driver import REQUEST_TOPIC

        raise ConnectError(f"{REQUEST_TOPIC}: nobody serves the simulated operator on {domain_text()}; start "
                           "`rig sim`, or set [operator] driver = 'console' in rig.toml for a person at this terminal")
    # rates over a short window, for the report
    window = 0.25
    arm0 = {n: rig.arms[n].received for n in names}
    mocap0 = dict(rig.tracker.stats.received) if rig.tracker is not None else {}
    cells = list(rig.forces.values()) if rig.forces else ([rig.force] if rig.force is not None else [])
    lc0 = [c.stats().samples for c in cells]
    tb = rig.session.time if rig.session is not None else None
    t0 = tb.now() if tb is not None else time.monotonic()
    if tb is not None:
        tb.sleep(window)  # on simulated time: a window of the world's time (the world freed meanwhile)
    else:
        time.sleep(window)
    window = (tb.now() if tb is not None else time.monotonic()) - t0 or window
    rates = {rig.arms[n].topic["measured_js"]: (rig.arms[n].received - arm0[n]) / window for n in names}
    parts = [f"{n} {rates[rig.arms[n].topic['measured_js']]:.0f} Hz" for n in names]
    for i, (cell, n0) in enumerate(zip(cells, lc0)):
        lc_rate = (cell.stats().samples - n0) / window
        rates["loadcell" if i == 0 else f"loadcell{i}"] = lc_rate
        ident = getattr(cell, "identity", None)
        parts.append(f"load cell {cell.name} {lc_rate:.0f} Hz"
                     + (f" (firmware {'.'.join(map(str, ident.firmware))})" if ident else ""))
    if rig.tracker is not None:
        body_rates = [(rig.tracker.stats.received[b] - mocap0[b]) / window for b in rig.tracker.bodies]
        rates["mocap"] = min(body_rates)
        parts.append(f"mocap {len(rig.tracker.bodies)} bodies {min(body_rates):.0f}-{max(body_rates):.0f} Hz")
    clock = rig.session.time.describe() if rig.session is not None else "the wall clock"
    say("connected: " + "; ".join(parts) + f"; running on {clock}")
    if rig.session is not None and not rig.session.time.simulated:
        stamps = [rig.arms[n].last_stamp() for n in names]
        if any(0.0 <= s < SIMULATED_BEFORE for s in stamps):
            raise ConnectError(f"{rig.arms[names[0]].topic['measured_js']}: stamped {min(stamps):.3f} s, a simulator's "
                               f"clock (`rig sim --sim-time`), while this rig runs on the wall clock: set [ros] "
                               f"use_sim_time = true in {cfg.source} (or start rig sim without --sim-time)")
    check_stream_rates(rig, cfg, names, rates, loop_rate)
    return rates


#: s: header stamps before this (2001-09-09) are a simulator's clock, not the epoch's
SIMULATED_BEFORE = 1e9

#: a stream heard below this fraction of the rate the rig's loop needs is refused
RATE_MARGIN = 0.6


def check_stream_rates(rig: Rig, cfg, names: list[str], rates: dict, loop_rate: float | None = None) -> None:
    """Refuse, in one line, arms whose measured_js is published slower than the rig's loop needs.

    The rate published is read from the messages' header stamps (`RosArm.published_rate`),
    not from how many arrived: a process starved of CPU reads a healthy stream late, and
    must not take it for a slow console. Every control tick of a run on ROS arms waits for a fresh measured_js of every arm
    (`rig.devices.clock.StreamClock` at [rig] rate): a console publishing at 100 Hz (`dvrk_system`'s
    default `-p 0.01`) would run a 500 Hz loop at 100 Hz, where the effort loops of the
    procedures are not stable. The line names the rate heard, the rate needed and the
    console option to change. `loop_rate`: the rate needed, if not [rig] rate (a procedure
    whose arms close their own loops, e.g. `rig cooperative` on servo_ci)."""
    needed = float(loop_rate if loop_rate is not None else cfg.rig["rate"])
    for n in names:
        arm = rig.arms[n]
        topic = arm.topic["measured_js"]
        rate = getattr(arm, "published_rate", None)
        heard = rate() if rate is not None else rates.get(topic, 0.0)
        if heard < RATE_MARGIN * needed:
            period = 1.0 / needed
            why = f"[rig] rate in {cfg.source}" if loop_rate is None else "this procedure's lowest"
            lower = f", or lower [rig] rate to {max(1, int(heard)):d}" if loop_rate is None else ""
            raise ConnectError(
                f"{topic}: heard at {heard:.0f} Hz (published, from its stamps), the rig's loop needs {needed:g} Hz "
                f"({why}): start the dVRK console with `dvrk_system -p {period:g}` (or `rig sim --ros-period "
                f"{period:g}`){lower}")


#: s an arm whose measured_js came is given for its first operating_state
STATE_GRACE = 2.0


def ready_arms(rig: Rig, names: list[str], timeout: float, say) -> None:
    """Enable and home the ROS arms `names` through their operating state, all at once,
    and wait up to `timeout` s for each to be ENABLED and homed (`RosArm.ready`); then
    for the measured_js of each.

    An arm that shows no operating_state within STATE_GRACE s of its joints (a controller
    without the CRTK state machine) is reported and used as before: its state is not read
    and move_jp waits on positions. Raises ArmFault (an arm in FAULT or PAUSED, or not
    ready in time) or ConnectError (no measured_js) with one line.
    """
    from concurrent.futures import ThreadPoolExecutor

    from drivers.common.ros_session import domain_text

    arms = {n: rig.arms[n] for n in names}
    grace_end = time.monotonic() + STATE_GRACE
    for arm in arms.values():
        arm.wait_for_state(max(0.0, grace_end - time.monotonic()))
    stateful = {n: a for n, a in arms.items() if a.operating_state() is not None}
    for n, arm in arms.items():
        if n not in stateful:
            why = arm.states_error or f"none within {STATE_GRACE:g} s"
            say(f"  {arm.topic['operating_state']}: {why}; {n}'s state is not read (move_jp waits on its joints)")
    if stateful:
        t0 = time.monotonic()
        before = {n: a.operating_state() for n, a in stateful.items()}
        todo = [n for n, st in before.items() if not st.ready or st.is_busy]
        if todo:
            say(f"  enabling and homing {', '.join(todo)} ("
                + "; ".join(f"{n} {before[n].describe()}" for n in todo) + f"; up to {timeout:g} s)")
        with ThreadPoolExecutor(max_workers=len(stateful)) as pool:
            futures = [pool.submit(a.ready, timeout) for a in stateful.values()]
            errors = [f.exception() for f in futures]
        first = next((e for e in errors if e is not None), None)
        if first is not None:
            raise first
        say(f"  {', '.join(stateful)}: ENABLED and homed "
            + (f"in {time.monotonic() - t0:.1f} s" if todo else "(as the last run left them)"))
    deadline = time.monotonic() + timeout
    for n, arm in arms.items():
        if not arm.wait_for_data(max(0.0, deadline - time.monotonic())):
            raise ConnectError(f"{arm.topic['measured_js']}: no message within {timeout:g} s of {n} being enabled "
                               f"on {domain_text()}; check that the dVRK (or `rig sim`) publishes it")


def _open_loadcell(lc: dict, rig: Rig):
    """The configured cell, with the newest calibration of that cell (made on its port;
    rig.devices.loadcell_calibrations.load_latest_calibration)."""
    from drivers.loadcell.serial_driver import LoadCell
    from rig.devices.loadcell_calibrations import load_latest_calibration

    calibration = load_latest_calibration(lc["port"] if lc["driver"] == "serial" else None)
    if lc["driver"] == "serial":
        from drivers.loadcell.serial_port import open_serial_port

        port = open_serial_port(lc["port"], lc["baudrate"])
        rig._closers.append(port.close)
        # sample times on the rig's clock, so the run compares them with its own time
        cell = LoadCell(port, calibration, rate_hz=int(round(lc["rate"])), stale_timeout=lc["stale_timeout"],
                        clock=rig.clock.now, time_base=rig.session.time if rig.session is not None else None)
        # on simulated time the cell is one of its time base's syncs: the loop reads the force
        # of a period once its bytes are read
    else:
        import can

        from drivers.loadcell.can import CanLoadCell

        bus = can.Bus(interface=lc["interface"], channel=lc["channel"])
        rig._closers.append(bus.shutdown)
        cell = CanLoadCell(bus, calibration, rate_hz=int(round(lc["rate"])), stale_timeout=lc["stale_timeout"],
                           clock=rig.clock.now)
    rig._closers.append(cell.close)
    return cell

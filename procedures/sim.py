"""`rig sim`: serve the simulated rig over the real device protocols, like a dVRK console and its lab.

One process, paced to the wall clock (`rig.sim_server.ros_node.SimServer`): every arm of the
configuration as a whole dVRK 2.4 PSM on its CRTK ROS 2 topics (six joints and the jaw,
the large needle driver unless `--tool` names another, the streams every `--ros-period`
s as `dvrk_system -p`, operating_state and the other events on change, the kinematics
services, `/system` or `/console` names), mocap poses on ROS 2 (and Motive's NatNet with
`--natnet`), each load cell's firmware fake on a pseudo-terminal (`drivers.loadcell.fake_firmware_process`;
the configured port becomes a link to it), and the operator's side channel: the manual
steps of a procedure done by a simulated person, the faults a test injects.

The object starts off the arms, as a lab's rig does: a procedure asks the operator to
attach it, and plain dVRK scripts meet free arms.

Prints `ready` when serving, and the achieved measured_js rate at exit (SIGINT/SIGTERM or
--duration).
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
import signal
import sys
import threading
import time

import click

from drivers.common import ros_exit
from rig.commands.exit_codes import InputError
from rig.commands.procedure import procedure_command
from rig.sim_server.ros_node import DVRK_ROS_PERIOD

STEPS = ("build the simulated world", "start the load cell on a pty", "create the ROS 2 node and topics",
         "serve until stopped")


def _say(text: str) -> None:
    print(text, flush=True)


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


def _ask_priority(nice: int) -> None:
    """Run at `nice` if the OS allows it. The served world stands in for a console whose
    servo loops never fall behind; on a machine shared with other programs (a procedure in
    the next terminal, a build, a test suite) a world at the default priority gets a fair
    share of a core and falls behind the wall clock, and a procedure's plan, on the wall
    clock, then outruns the simulated arms (measured: 77 % of real time at
    `--ros-period 0.01`, 50 to 63 % of a core, on this 2-core machine under load)."""
    import os

    current = os.getpriority(os.PRIO_PROCESS, 0)
    if nice >= current:
        if nice > current:
            os.setpriority(os.PRIO_PROCESS, 0, nice)
        return
    try:
        os.setpriority(os.PRIO_PROCESS, 0, nice)
    except PermissionError:
        _say(f"rig sim: runs at nice {current}, not {nice} (raising the priority needs root or CAP_SYS_NICE): "
             "on a busy machine the simulated arms may fall behind the wall clock")


@procedure_command("sim", STEPS, steps_help="List the steps and exit.", yes=False, json=False, abort=False,
                   echo=_say)
@click.option("--arms", default=None, help="Comma-separated arms to serve (default: every arm of the configuration, e.g. PSM1,PSM2).")
@click.option("--duration", type=float, default=None, help="Stop after this many seconds (default: until Ctrl-C or SIGTERM).")
@click.option("--rate", type=float, default=None,
              help="Servo rate of the simulated arms (physics and controllers), Hz (default: the configuration's "
                   "[rig] rate, 1000).")
@click.option("--ros-period", type=float, default=DVRK_ROS_PERIOD, show_default=True,
              help="Seconds between two publications of every arm stream (measured_js, setpoint_js, measured_cp, "
                   "...), as `dvrk_system -p`. The default is the dVRK console's own default, so scripts meet what a "
                   "lab's console gives them; procedures that close a loop over the arms' efforts in Python need "
                   "0.002 or 0.001 (they say so when they connect).")
@click.option("--tool", default=None,
              help="The PSMs' tool, as the dVRK names its tool files (default LARGE_NEEDLE_DRIVER_400006; "
                   "`rig sim --tool list` lists them).")
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
@click.option("--nice", "nice", type=click.IntRange(-20, 19), default=-10, show_default=True,
              help="Scheduling priority (nice value) rig sim asks for: a dVRK console runs its servo loops at "
                   "real-time priority and never falls behind; below 0 needs root or CAP_SYS_NICE (if refused, "
                   "rig sim says so and runs at the priority it has).")
@click.option("--sim-time/--wall-time", "sim_time", default=False, show_default=True,
              help="Run on simulated time: publish the world's time on /clock and stamp every message with it, as "
                   "Gazebo does; procedures follow it with [ros] use_sim_time = true. A loaded machine then runs "
                   "the world slower than real time, and the procedures with it. The default, the wall clock, is "
                   "what a real dVRK console keeps.")
@click.option("--lockstep/--no-lockstep", default=True, show_default=True,
              help="With --sim-time: the world does not step past a ROS period until every procedure that follows "
                   "its clock has answered it, so nothing a procedure computes depends on how fast the machine is; "
                   "with no procedure following, the world runs in real time. --no-lockstep: the world runs in real "
                   "time always (a simulated clock only).")
@click.option("--lockstep-timeout", type=click.FloatRange(min=0.1), default=3.0, show_default=True,
              help="With --lockstep: seconds of wall time a procedure may go silent (a live one repeats its "
                   "answer five times a second, computing or waiting) before the world steps on without it: a killed "
                   "procedure never freezes rig sim; it rejoins with its next answer.")
@click.option("--servo-ci/--no-servo-ci", "servo_ci", default=True, show_default=True,
              help="Subscribe to every arm's servo_ci as a dVRK 2.2+ console's ROS bridge does; --no-servo-ci "
                   "serves a console whose bridge does not (what `rig doctor` and `rig cooperative` must see).")
def command(ctx, arms, duration, rate, ros_period, tool, seed, loadcell, mocap, natnet, natnet_version, console,
            plant_model, nice, sim_time, lockstep, lockstep_timeout, servo_ci):
    """Serve the simulated rig as whole dVRK PSMs on their ROS 2 topics (/<ARM>/measured_js ...
    every ROS_PERIOD s), mocap poses on /mocap/<body>/pose and the load cell on a pty, paced
    to the wall clock. The dVRK's own Python client (dvrk_python, crtk) drives it unmodified.

    Every arm of the configuration is served, whatever its driver, so one rig.toml (ROS
    arms, a serial load cell, ROS mocap, [operator] driver = "ros") serves here and drives
    the procedures in another process. The manual steps of a procedure (take the object
    off, attach it, hang masses on the load cell, touch a point) are done by the
    simulation when asked on /rig_sim/operator/request.

    Prints 'loadcell: <pty>' and then 'ready' when serving; prints the achieved
    measured_js rate at exit. Use ROS_DOMAIN_ID and ROS_AUTOMATIC_DISCOVERY_RANGE to choose
    who sees it.
    """
    from rig.model.psm_tool import TOOL_NAMES

    if tool == "list":
        for name in TOOL_NAMES:
            _say(name)
        return
    if tool is not None and tool not in TOOL_NAMES:
        raise click.BadParameter(f"no tool {tool!r}; tools: {', '.join(TOOL_NAMES)}", param_hint="--tool")
    from rig.sim.world import world_from_config

    from drivers.common import crtk_messages

    if crtk_messages.problem() is not None:  # a dVRK console's arms speak them
        raise InputError(f"rig sim serves the dVRK's CRTK messages: {crtk_messages.problem()}")
    _ask_priority(nice)  # before any thread starts: Linux keeps a nice value per thread, new ones inherit it
    cfg, names, rate, console, natnet, natnet_host = _served(ctx, arms, rate, ros_period, plant_model, console, natnet)
    world = world_from_config(cfg, arms=names, seed=seed)
    # the object's spec and elements are known (a load cell per element); it starts off the arms
    object_spec = world.object
    elements = list(world.object_elements)

    stop = threading.Event()

    def on_signal(signum, _frame):
        stop.set()

    firmwares, cells, links = _serve_loadcells(cfg, world, elements, loadcell, sim_time)

    import rclpy
    from rclpy.context import Context

    from rig.sim_server.ros_node import SimServer
    from rclpy.signals import SignalHandlerOptions

    ros_exit.before_init()
    context = Context()
    # Our own handlers stop the loop cleanly; rclpy's would shut the context under it.
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    node = server = None
    try:
        node = rclpy.create_node("rig_sim", context=context)
        ros_exit.after_node()
        mocap_cfg = dict(cfg.mocap) if mocap and cfg.mocap["driver"] != "none" else None
        if world.object is not None:
            world.detach_object()
        for cell in cells:
            cell.update()
        server = SimServer(world, node, list(world.names), ros_period=ros_period, mocap=mocap_cfg, seed=world.seed,
                           console=console, cells=cells, executor=cfg.ros["executor"], object_spec=object_spec,
                           tool=tool, sim_time=sim_time, lockstep=lockstep, lockstep_timeout=lockstep_timeout,
                           servo_ci=servo_ci)
        server.stop = stop
        if natnet:
            server.natnet = _serve_natnet(cfg, world, server, natnet_host, natnet_version)
        # Installed after rclpy is up: its initialisation replaces SIGINT/SIGTERM handlers.
        signal.signal(signal.SIGINT, on_signal)
        signal.signal(signal.SIGTERM, on_signal)
        _say_serving(world, server, rate, sim_time, lockstep, console)
        stats = server.serve(duration, on_ready=lambda: _say("ready"))
    finally:
        _close(server, firmwares, links, node, context)
    _say_stats(stats, server, rate, sim_time)


def _served(ctx, arms, rate, ros_period, plant_model, console, natnet):
    """The configuration rig sim serves, checked: (cfg, arm names, servo rate Hz, console
    name, whether NatNet is served, its host)."""
    from rig.commands.options import config_from_context

    cfg = served_config(config_from_context(ctx))
    rate = cfg.rig["rate"] if rate is None else rate
    if rate <= 0:
        raise click.BadParameter("the rate must be > 0 Hz", param_hint="--rate")
    if not (0.0 < ros_period <= 1.0):
        raise click.BadParameter(f"the ROS period must be in (0, 1] s, got {ros_period:g} s (a period shorter "
                                 "than the servo period publishes every servo period)", param_hint="--ros-period")
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

        from drivers.natnet.fake_motive import check_loopback

        try:
            natnet_host = check_loopback(_socket.gethostbyname(cfg.mocap["server"]))
        except (ValueError, OSError):
            raise click.BadParameter(f"the fake Motive serves on this machine's loopback only, and [mocap] server in "
                                     f"{cfg.source} is {cfg.mocap['server']!r}: set it to '127.0.0.1'",
                                     param_hint="--natnet") from None
    return cfg, names, rate, console, natnet, natnet_host


def _serve_loadcells(cfg, world, elements, loadcell: bool, sim_time: bool):
    """One emulated Arduino per object element (its firmware on a pty), and the configured
    ports linked to them: (firmwares, the cells' loads, links)."""
    from drivers.operator.sim import CellLoad

    object_spec = world.object
    firmwares, cells, links = [], [], []
    if loadcell and cfg.loadcell["driver"] != "none" and object_spec is not None:
        from drivers.loadcell.fake_firmware_process import FakeFirmwareProcess

        first = min(cfg.loadcell["element"], len(elements) - 1)
        order = [first] + [k for k in range(len(elements)) if k != first]
        for k in order:
            fw_kwargs = dict(noise=cfg.loadcell["noise"], rate_hz=int(round(cfg.loadcell["rate"])),
                             seed=world.seed + 7 * k)
            if sim_time:
                # on simulated time the "Arduino" converts on the world's clock, stepped by the
                # world's loop: its samples are where the world is, however fast that runs
                from drivers.loadcell.fake_firmware import FakeLoadCellFirmware

                cell = CellLoad(world, k)
                # its micros() is the world's time, as the samples' stamps on simulated time
                fw = FakeLoadCellFirmware(cell, clock=lambda: world.t, micros_start=int(round(world.t * 1e6)),
                                          **fw_kwargs)
                cell.pump, cell.cable = fw.pump, fw.unplug
            else:
                # each "Arduino" in its own process: its samples keep their pace whatever this
                # loop is doing (see drivers.loadcell.fake_firmware_process)
                fw = FakeFirmwareProcess(**fw_kwargs)
                cell = CellLoad(world, k, sink=fw.set_tension, cable=fw.unplug)
            firmwares.append(fw)
            cell.update()
            cells.append(cell)
            a, b = elements[k]
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
    return firmwares, cells, links


def _serve_natnet(cfg, world, server, natnet_host, natnet_version):
    """The fake Motive on the loopback, fed by the world (started)."""
    from drivers.natnet.fake_motive import FakeMotiveOnWorld, parse_version

    m = cfg.mocap
    try:
        # Motive's clock counts from before its first frame, as a PC's counter does
        natnet = FakeMotiveOnWorld(world, server.clock, noise=m["noise"], latency=m["latency"],
                                   occlusion=m["occlusion"], rate=m["rate"], seed=world.seed + 1,
                                   host=natnet_host, command_port=m["command_port"], data_port=m["data_port"],
                                   multicast=m["multicast"], version=parse_version(natnet_version),
                                   epoch=time.time() - 3600.0).start()
    except OSError as exc:
        raise InputError(
            f"cannot serve NatNet on {natnet_host}:{m['command_port']} (data {m['data_port']}): "
            f"{exc.strerror or exc}; another Motive or `rig sim --natnet` serves there: stop it, or set "
            f"[mocap] command_port and data_port in {cfg.source}") from None
    _say(f"natnet: {natnet_host}:{m['command_port']} (data {m['data_port']}, "
         f"{'multicast ' + m['multicast'] if m['multicast'] else 'unicast'}, NatNet {natnet_version}, "
         f"{m['rate']:g} Hz)")
    return natnet


def _say_stats(stats: dict, server, rate: float, sim_time: bool) -> None:
    """What rig sim achieved, at exit: rates, real-time factor, lockstep, refusals."""
    target = 1.0 / (server.ros_every / rate)
    common = (f"refused commands {stats['command_errors']}, superseded {stats['superseded']}, dropped (arm not "
              f"ready) {sum(stats['dropped'].values())}, operator requests {sum(server.operator.served.values())}")
    if sim_time:
        # per simulated second: the streams keep their period on the world's clock
        sim = stats["sim_s"]
        rates = ", ".join(f"{n} {c / sim if sim > 0 else 0.0:.1f} Hz" for n, c in server.published.items())
        ls = stats.get("lockstep")
        _say(f"measured_js published: {rates} of simulated time (target {target:g} Hz); {sim:.3f} s simulated in "
             f"{stats['wall_s']:.3f} s wall (real-time factor {stats['real_time_factor']:.2f})"
             + ("" if ls is None else f"; lockstep: {ls['followed_sim_s']:.1f} s simulated while procedures "
                f"followed, in {ls['followed_wall_s']:.1f} s wall (real-time factor followed {ls['real_time_factor']:.2f}), "
                f"waited {ls['wait_s']:.1f} s for answers, let go of {ls['lost']} silent procedure(s), "
                f"{ls['late_commands']} command(s) taken as come")
             + f"; {common}")
        return
    hz = stats["measured_js_hz"]
    rates = ", ".join(f"{n} {v:.1f} Hz" for n, v in hz.items())
    held = all(v >= 0.98 * target for v in hz.values())
    _say(f"measured_js achieved: {rates} (target {target:g} Hz{'' if held else ', NOT held'}); "
         f"{stats['sim_s']:.3f} s simulated in {stats['wall_s']:.3f} s wall; late ticks {stats['late_ticks']} (longest "
         f"{stats['max_lag_s'] * 1e3:.1f} ms behind), re-anchored {stats['slips']}, {common}")


def _say_serving(world, server, rate: float, sim_time: bool, lockstep: bool, console: str) -> None:
    print(f"rig sim: serving {', '.join(world.names)} ({server.psms[world.names[0]].tool.name}; servo "
          f"{rate:g} Hz, ROS period {server.ros_every / rate:g} s; "
          + ("the wall clock" if not sim_time else "simulated time on /clock" + (", lockstep" if lockstep else ""))
          + ") on ROS_DOMAIN_ID="
          f"{os.environ.get('ROS_DOMAIN_ID', '0')}, console {console}, operator on /rig_sim/operator",
          file=sys.stderr, flush=True)


def _close(server, firmwares, links, node, context) -> None:
    """Everything rig sim served, closed however it ended; the links to the ptys removed."""
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
    ros_exit.teardown(node, context)

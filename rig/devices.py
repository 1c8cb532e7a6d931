"""The device factory procedures call: `open_rig(cfg) -> Rig` (clock, arms, force sensor, tracker).

This is the one place that decides simulated or real, from the configuration, so no
procedure or driver needs an `if simulated:` branch.

* Simulated arms (driver "sim"): one `SimWorld` from `world_from_config`, a `SimClock`
  stepping it (faster than real time unless `rig.pace`), `SimArm`s, the load cell as
  `SimForceSensor` (the firmware's device model and byte framing on simulated time; see
  `drivers.loadcell_sim` for why not the pty fake) and mocap as `SimTracker`.
* Real arms (driver "ros"): a `WallClock` at `rig.rate`, one rclpy context and node owned
  by the Rig and spun by one executor thread, `RosArm`s on it (watchdog from each arm's
  config), the serial or CAN `LoadCell` and `RosMocapTracker` on the same node.

Mixing simulated and real arms in one rig is refused: they would live on different clocks.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any

from rig.clock import SimClock, WallClock


@dataclass
class Rig:
    """What a procedure drives. `world` is the simulated world (None on the real rig)."""

    clock: Any
    arms: dict[str, Any]
    force: Any | None = None
    # One force sensor per object element, in the world's element order. The simulated rig
    # puts a load cell on every element (three arms hold a triangle); a real rig has the
    # one configured load cell, on element `loadcell.element`.
    forces: dict = field(default_factory=dict)
    tracker: Any | None = None
    world: Any | None = None
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


def open_rig(cfg, arms: list[str] | None = None, *, seed: int | None = None) -> Rig:
    """Open the devices of `cfg` (a `rig.config.RigConfig`); `arms` limits which arms."""
    names = list(arms) if arms else list(cfg.arms)
    for n in names:
        if n not in cfg.arms:
            raise ValueError(f"{cfg.source}: no arm {n!r}; arms: {', '.join(cfg.arms)}")
    drivers = {cfg.arms[n]["driver"] for n in names}
    if len(drivers) > 1:
        raise ValueError(f"{cfg.source}: arms {names} mix simulated and ROS drivers; "
                         "run `rig sim` to serve the simulated ones over ROS 2 instead")
    if drivers == {"sim"}:
        return _open_simulated(cfg, names, seed)
    return _open_ros(cfg, names)


def _open_simulated(cfg, names: list[str], seed: int | None) -> Rig:
    from drivers.loadcell_sim import SimForceSensor
    from drivers.mocap_sim import SimTracker
    from drivers.sim_arm import SimArm
    from rig.sim import world_from_config

    world = world_from_config(cfg, arms=names, seed=seed)
    clock = SimClock(world)
    rig = Rig(clock=clock, arms={n: SimArm(world, n, clock) for n in names}, world=world)
    lc = cfg.loadcell
    if lc["driver"] != "none" and world.object is not None:
        for k in range(len(world.object_elements)):
            sensor = SimForceSensor(world, clock, element=k, rate=lc["rate"], noise=lc["noise"],
                                    seed=world.seed + 2 + 7 * k)
            rig.forces[k] = sensor
            rig._closers.append(sensor.close)
        rig.force = rig.forces[min(lc["element"], len(rig.forces) - 1)]
    m = cfg.mocap
    if m["driver"] != "none":
        rig.tracker = SimTracker(world, clock, noise=m["noise"], latency=m["latency"],
                                 occlusion=m["occlusion"], rate=m["rate"], seed=world.seed + 1)
        rig._closers.append(rig.tracker.close)
    return rig


def _open_ros(cfg, names: list[str]) -> Rig:
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor

    from drivers.dvrk_arm import RosArm

    context = Context()
    rclpy.init(context=context)
    node = rclpy.create_node("rig", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    rig = Rig(clock=WallClock(cfg.rig["rate"]), arms={})

    def stop_ros() -> None:
        executor.shutdown(timeout_sec=1.0)
        node.destroy_node()
        if context.ok():
            rclpy.shutdown(context=context)

    rig._closers.append(stop_ros)
    try:
        for n in names:
            a = cfg.arms[n]
            arm = RosArm(node, a["namespace"], watchdog=a["watchdog"], spin=False)
            rig.arms[n] = arm
            rig._closers.append(arm.close)
        lc = cfg.loadcell
        if lc["driver"] in ("serial", "can"):
            rig.force = _open_loadcell(lc, rig)
            rig.forces = {lc["element"]: rig.force}
        elif lc["driver"] == "sim":
            raise ValueError(f"{cfg.source}: loadcell.driver = 'sim' needs simulated arms; with ROS arms "
                             "use 'serial' with the pty that `rig sim` prints (or 'none')")
        m = cfg.mocap
        if m["driver"] == "ros":
            from drivers.mocap import RosMocapTracker
            from rig.sim import default_marker_bodies

            bodies = [mb.name for n in names for mb in default_marker_bodies(n)] + ["world"]
            rig.tracker = RosMocapTracker(node, bodies, prefix=m["prefix"])
            rig._closers.append(rig.tracker.close)
        # One executor thread for the node every driver shares (drivers only copy messages).
        thread = threading.Thread(target=_spin, args=(executor,), name="rig-ros", daemon=True)
        thread.start()
    except BaseException:
        rig.close()
        raise
    return rig


def _spin(executor) -> None:
    try:
        executor.spin()
    except Exception:  # noqa: BLE001 - the context is shut down by Rig.close()
        pass


def _open_loadcell(lc: dict, rig: Rig):
    from drivers.loadcell import LoadCell, load_latest_calibration

    calibration = load_latest_calibration()
    if lc["driver"] == "serial":
        import serial

        port = serial.Serial(lc["port"], lc["baudrate"], timeout=0.005)
        rig._closers.append(port.close)
        cell = LoadCell(port, calibration, rate_hz=int(round(lc["rate"])), stale_timeout=lc["stale_timeout"])
    else:
        import can

        from drivers.loadcell_can import CanLoadCell

        bus = can.Bus(interface=lc["interface"], channel=lc["channel"])
        rig._closers.append(bus.shutdown)
        cell = CanLoadCell(bus, calibration, rate_hz=int(round(lc["rate"])), stale_timeout=lc["stale_timeout"])
    rig._closers.append(cell.close)
    return cell

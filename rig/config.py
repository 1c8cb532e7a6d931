"""Rig configuration: `rig.toml` names the arms and each device's driver and settings.

With no file the built-in simulated rig is used: PSM1 and PSM2 facing each other with
their tool tips 0.10 m apart, a 2450 N/m spring between the tips, a load cell on it and a
mocap system. Every key is declared once below (type, default, allowed values, units);
an unknown key, a wrong type or an impossible value raises `ConfigError` with one line
naming the file, the key and what is allowed.

Example (a real rig)::

    [rig]
    seed = 0

    [arms.PSM1]
    driver = "ros"
    namespace = "/PSM1"

    [arms.PSM2]
    driver = "ros"
    base_xyz = [1.0728, 0.0, 0.0]   # m, frame 0 of PSM2 in the world
    base_rpy = [0.0, 0.0, 3.14159]  # rad

    [loadcell]
    driver = "serial"
    port = "/dev/ttyACM0"

    [mocap]
    driver = "ros"

Simulated arms may carry hidden effects for the discrepancy workflow and tests::

    [effects.PSM1]
    stiction = [0.0, 0.0, 1.0]      # breakaway level per joint (N m, N m, N)

or take their whole plant from a model file, such as the augmented model `rig discrepancy`
writes (parameters and added effects; see `rig.model.model_file.IdentifiedModel.plant`)::

    [arms.PSM1]
    plant_model = "logs/20261121T101500Z-discrepancy/model.json"
"""

from __future__ import annotations

import copy
import dataclasses
import difflib
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from drivers.loadcell.protocol import BAUDRATE as LOADCELL_BAUDRATE
from drivers.loadcell.protocol import FIRMWARE_MAX_RATE_HZ as LOADCELL_MAX_RATE


class ConfigError(ValueError):
    """A configuration problem, as one line naming the file, the key and what is allowed."""


@dataclass(frozen=True)
class Key:
    kind: str                     # "float", "int", "bool", "str", "vec3", "strlist", "mat4"
    default: Any
    help: str
    check: Callable[[Any], bool] | None = None
    allowed: str = ""             # what the check allows, in words


def _positive(x) -> bool:
    return x > 0


def _nonneg(x) -> bool:
    return x >= 0


def _nonneg3(v) -> bool:
    return all(x >= 0 for x in v)


def _port(x) -> bool:
    return 1 <= x <= 65535


def _multicast_group(x) -> bool:
    import ipaddress

    if x == "":
        return True
    try:
        addr = ipaddress.ip_address(x)
    except ValueError:
        return False
    return addr.version == 4 and addr.is_multicast


def _choice(*options: str) -> tuple[Callable[[Any], bool], str]:
    return (lambda x: x in options), "one of " + ", ".join(repr(o) for o in options)


_DRIVER_ARM = _choice("sim", "ros")
_DRIVER_LOADCELL = _choice("sim", "serial", "can", "none")
_DRIVER_MOCAP = _choice("sim", "ros", "natnet", "none")
_OBJECT_KIND = _choice("spring", "string")
_OPERATOR = _choice("console", "ros")

#: Hz: the rig rate when the file names ROS arms and gives no [rig] rate. Python over rclpy
#: does not hold 1 kHz on a shared 2-core machine: bench/bench_hil.py measures it (the
#: thesis's own controller ran at 400-500 Hz).
ROS_DEFAULT_RATE = 500.0
#: Hz: the same with three ROS arms or more. Each cycle reads, controls, records and
#: commands every arm; with three arms the cooperative loop reached 190-330 Hz of 500 and
#: aborted on the effort ceiling, at 250 Hz it held 5 N within 0.09-0.10 N (bench_hil).
ROS_DEFAULT_RATE_MANY_ARMS = 250.0
#: Stale limits (the arms' `watchdog`, the load cell's and the mocap's `stale_timeout`):
#: a stream is stale after STALE_PERIODS of its periods without a message, but never
#: sooner than the floor of its transport. The periods: a healthy stream may lose a few
#: messages in a row (best-effort ROS, a CAN error frame, an occluded body); ten in a row
#: is a stream that stopped. The floor: silence alone cannot tell a stopped device from a
#: process held off the CPU (this one, or the publisher: `rig sim`, the console, a bridge),
#: so the floor is how long such a process was held on the machine the rig runs on.
#: Measured over the wire on this 2-core machine (`rig sim` and the procedures as two
#: processes, two CPU burners beside them, and other users' work: load average 15-26):
#: the longest age the drivers' watchdogs computed (counted up to their executor's or
#: reader's last look, so a starved subscriber is already discounted) during link-lengths,
#: calibrate-rcm and friction-ramp was, at `rig sim --ros-period` 0.001/0.002 s,
#: measured_js 0.25-1.26 s in single runs (1.8 s with a second rig beside it) and mocap
#: poses 0.30-1.24 s (1.9 s). Those ages are not the procedure's Python held off the CPU
#: (its executor kept looking and found nothing): the messages were held up at the
#: publisher or in transit (DDS's own threads included), which no subscriber can tell
#: from a stopped device. Hence 2.0 s for ROS 2 and NatNet streams. A
#: serial cell's reader is the only one counting: its age stayed under 12 ms while samples
#: reached the procedure up to 0.92 s apart (the procedure held off the CPU, discounted),
#: and bytes written to a pty reach the reader up to ~0.35 s late under two burners
#: (bench/bench_hil.py), hence 0.5 s.
STALE_PERIODS = 10
#: s: floor of the stale limit of a ROS 2 stream (arms' measured_js, mocap poses) or NatNet
ROS_STALE_FLOOR = 2.0
#: s: floor of the stale limit of a serial or CAN load cell
SERIAL_STALE_FLOOR = 0.5
#: s: floor of an in-process simulated device's: it runs on the simulated clock, which a
#: busy machine slows but never makes skip, so only the periods count (and 50 ms at least)
SIM_STALE_FLOOR = 0.05
#: s: floor of a ROS 2 stream's stale limit on simulated time ([ros] use_sim_time): the age
#: is counted on the simulator's clock, which a starved process (this one or `rig sim`)
#: slows but never outruns (lockstep: the world waits for this process's answers), so the
#: floor covers only the periods the world may run ahead of a free process's last answer
#: and the messages' order between topics
SIM_TIME_STALE_FLOOR = 0.25
#: s: the dVRK console's publishing period unless started with another `dvrk_system -p`
DVRK_DEFAULT_PERIOD = 0.01


def stale_default(period: float, floor: float) -> float:
    """The default stale limit of a stream published every `period` s: STALE_PERIODS
    periods, or `floor` s if longer (see above)."""
    return max(STALE_PERIODS * period, floor)


SCHEMA: dict[str, dict[str, Key]] = {
    "rig": {
        "seed": Key("int", 0, "seed of the simulated rig's random numbers"),
        "rate": Key("float", 1000.0, "rig (servo) rate, Hz (default 1000; 500 when the arms are ROS arms, "
                    "250 with three ROS arms or more)",
                    _positive, "a rate > 0 Hz"),
        "pace": Key("bool", False, "pace the simulated rig to the wall clock"),
        "gravity": Key("vec3", [0.0, 0.0, -9.81], "gravity in the world frame, m/s^2"),
    },
    "arm": {
        "driver": Key("str", "sim", "arm driver", *_DRIVER_ARM),
        "namespace": Key("str", "", "ROS 2 namespace of the arm's CRTK topics (default /<name>)"),
        "serial": Key("str", "", "serial number of a dVRK arm (as in its sawIntuitiveResearchKit configuration "
                      "file, e.g. '28007'): results measured on it name it, and are used only on it"),
        "base_xyz": Key("vec3", [0.0, 0.0, 0.0], "position of the arm's frame 0 in the world, m"),
        "base_rpy": Key("vec3", [0.0, 0.0, 0.0], "orientation of frame 0 in the world (roll, pitch, yaw), rad"),
        "q0": Key("vec3", [0.0, 0.0, 0.12], "start joints (rad, rad, m): a simulated arm starts there; `rig "
                  "cooperative` moves a real arm there, the object off, before asking for the object"),
        "effort_limit": Key("vec3", [5.0, 5.0, 15.0], "drive effort ceiling (N m, N m, N)",
                            lambda v: all(x > 0 for x in v), "three efforts > 0"),
        "watchdog": Key("float", SIM_STALE_FLOOR, "s without a measured_js that stops the run (the arm is told to "
                        "hold): the stale limit of a ROS arm. Default: 10 of the console's periods ([ros] period) "
                        "or 2.0 s, whichever is longer (2.0 s at the dVRK's 100 Hz); the 2.0 s covers a process "
                        "held off the CPU on a busy 2-core machine, which looks the same as a stopped console. A "
                        "simulated arm in this process runs on the simulated clock: 10 rig periods, 0.05 s at "
                        "least", _positive, "an interval > 0 s"),
        "sensor_noise": Key("bool", True, "simulate encoder quantisation and velocity/effort noise"),
        "plant_model": Key("str", "", "model file (the model.json of `rig identify` or `rig discrepancy`) whose "
                           "parameters and effects a simulated arm's plant takes (default: the nominal PSM); "
                           "a relative path is taken from the configuration file's folder"),
    },
    "loadcell": {
        "driver": Key("str", "sim", "load-cell driver", *_DRIVER_LOADCELL),
        "port": Key("str", "", "serial port of the Arduino (driver = serial; a relative path is taken from the "
                    "configuration file's folder)"),
        "ports": Key("strlist", [], "serial ports of one load cell per object element, in the elements' order "
                     "(PSM1-PSM2, PSM1-PSM3, PSM2-PSM3 for three arms; driver = serial); replaces port"),
        "baudrate": Key("int", LOADCELL_BAUDRATE, "serial baud rate (the rig's firmware's)", _positive,
                        "a baud rate > 0"),
        "interface": Key("str", "socketcan", "python-can interface (driver = can)"),
        "channel": Key("str", "can0", "python-can channel (driver = can)"),
        "rate": Key("float", 500.0, "sample rate, Hz (the firmware's limit: 1000 Hz for the INA build, 80 Hz for "
                    "the HX711's)", lambda x: 1 <= x <= LOADCELL_MAX_RATE,
                    f"a rate in [1, {LOADCELL_MAX_RATE}] Hz (the firmware's MAX_RATE_HZ; 80 for the HX711 build)"),
        "stale_timeout": Key("float", SIM_STALE_FLOOR, "s without a sample that stops the run: the load cell's "
                             "stale limit. Default: 10 sample periods (1 / rate) or, if longer, 0.5 s for a serial "
                             "or CAN cell (a process held off the CPU looks the same as a pulled cable) and 0.05 s "
                             "for the simulated one", _positive, "an interval > 0 s"),
        "noise": Key("float", 0.02, "simulated load-cell noise, N rms", _nonneg, "a noise >= 0 N"),
        "element": Key("int", 0, "which object element (pair of arms) the load cell sits on", _nonneg, "an index >= 0"),
    },
    "mocap": {
        "driver": Key("str", "sim", "motion-capture driver", *_DRIVER_MOCAP),
        "prefix": Key("str", "mocap", "ROS 2 topic prefix: /<prefix>/<body>/pose"),
        "server": Key("str", "127.0.0.1", "NatNet (driver = natnet): address of the Motive PC (127.0.0.1: `rig sim "
                      "--natnet` on this machine)", lambda x: bool(x.strip()), "a host name or IPv4 address"),
        "command_port": Key("int", 1510, "NatNet command port (Motive's default 1510)", _port, "a port in [1, 65535]"),
        "data_port": Key("int", 1511, "NatNet data port (Motive's default 1511)", _port, "a port in [1, 65535]"),
        "multicast": Key("str", "", "NatNet multicast group as set in Motive (e.g. '239.255.42.99'); empty: unicast",
                         _multicast_group, "'' (unicast) or an IPv4 multicast address (224.0.0.0-239.255.255.255)"),
        "rate": Key("float", 120.0, "frame rate, Hz", lambda x: 1 <= x <= 1000, "a rate in [1, 1000] Hz"),
        "stale_timeout": Key("float", ROS_STALE_FLOOR, "s without a pose of a body (ros) or a frame (natnet) that "
                             "stops the run: the mocap's stale limit. Default: 10 frame periods (1 / rate) or, if "
                             "longer, 2.0 s (a process held off the CPU looks the same as a stopped bridge or "
                             "Motive; 0.05 s for the simulated mocap)", _positive, "an interval > 0 s"),
        "noise": Key("float", 0.00025, "simulated marker noise, m rms", _nonneg, "a noise >= 0 m"),
        "latency": Key("float", 0.005, "simulated latency, s", _nonneg, "a latency >= 0 s"),
        "occlusion": Key("float", 0.0, "probability that a simulated body is occluded in a frame",
                         lambda x: 0 <= x < 1, "a probability in [0, 1)"),
    },
    "ros": {
        "console": Key("str", "auto", "namespace of the dVRK console's topics: '/console' (dVRK 2.3), '/system' "
                       "(dVRK 2.4), or 'auto' (whichever the running system publishes)",
                       lambda x: x == "auto" or (x.startswith("/") and len(x) > 1), "'auto' or a namespace like '/system'"),
        "period": Key("float", DVRK_DEFAULT_PERIOD, "s between the messages the dVRK console publishes (its "
                      "`dvrk_system -p`, `rig sim --ros-period`; the dVRK's default 0.01): the arms' default "
                      "watchdog is 10 of them, 2.0 s at least", _positive, "a period > 0 s"),
        "connect_timeout": Key("float", 15.0, "wait this long for the first message of every stream, s (ROS 2 discovery "
                               "can take seconds on a loaded machine)",
                               _positive, "an interval > 0 s"),
        "executor": Key("str", "events", "rclpy executor of the ROS 2 devices: 'events' (rclpy's EventsExecutor, about "
                        "a third of the CPU) or 'single' (SingleThreadedExecutor)", *_choice("events", "single")),
        "use_sim_time": Key("bool", False, "follow the simulator's /clock (`rig sim --sim-time`), as ROS's parameter of "
                            "that name: every loop, watchdog, timeout and recording stamp on simulated time (the ROS "
                            "streams' stale limits then default to 10 periods or 0.25 s). False: the wall clock, as "
                            "against a real dVRK console"),
        "lockstep": Key("bool", True, "with use_sim_time: answer every period of the simulator's clock, so that the "
                        "world waits for this process's control loop (`rig sim --lockstep`)"),
    },
    "operator": {
        "driver": Key("str", "console", "who does the manual steps (mount bodies, hang masses, attach the object): "
                      "'console' = a person at this terminal; 'ros' = `rig sim`'s simulated operator over ROS 2",
                      *_OPERATOR),
        "timeout": Key("float", 30.0, "wait this long for the simulated operator to answer, s", _positive,
                       "an interval > 0 s"),
        "yes": Key("bool", False, "console operator: take every request as done without waiting for Enter "
                   "(the rig is prepared beforehand); the --yes flag of a command sets it"),
    },
    "object": {
        "kind": Key("str", "spring", "simulated object between the tool tips", *_OBJECT_KIND),
        "stiffness": Key("float", 2450.0, "object stiffness, N/m (thesis springs: 2450)", _positive, "a stiffness > 0 N/m"),
        "damping": Key("float", 5.0, "object damping, N s/m", _nonneg, "a damping >= 0 N s/m"),
        "rest_length": Key("float", 0.10, "object rest length, m", _positive, "a length > 0 m"),
        "arms": Key("strlist", ["PSM1", "PSM2"], "arms holding the object"),
    },
    "effects": {
        "stiction": Key("vec3", [0.0] * 3, "breakaway friction level Fs per joint", _nonneg3, "levels >= 0"),
        "stribeck_velocity": Key("vec3", [0.01] * 3, "Stribeck velocity per joint", lambda v: all(x > 0 for x in v), "velocities > 0"),
        "coulomb_asymmetry": Key("vec3", [0.0] * 3, "Fc+ - Fc- per joint"),
        "position_friction": Key("vec3", [0.0] * 3, "relative amplitude of position-dependent Coulomb friction",
                                 lambda v: all(0 <= x < 1 for x in v), "amplitudes in [0, 1)"),
        "position_friction_period": Key("vec3", [0.8, 0.6, 0.08], "period of the position-dependent friction (rad, rad, m)",
                                        lambda v: all(x > 0 for x in v), "periods > 0"),
        "spring": Key("vec3", [0.0] * 3, "spring stiffness per joint (N m/rad, N m/rad, N/m)"),
        "spring_rest": Key("vec3", [0.0] * 3, "joint position where the spring is relaxed"),
        "payload_mass": Key("float", 0.0, "extra mass on the tool, kg", _nonneg, "a mass >= 0 kg"),
        "payload_com": Key("vec3", [0.0] * 3, "payload position in the tool frame, m"),
        "backlash": Key("vec3", [0.0] * 3, "play per joint (rad, rad, m)", _nonneg3, "plays >= 0"),
        "time_delay": Key("float", 0.0, "measured effort delay, s", lambda x: 0 <= x <= 0.5, "a delay in [0, 0.5] s"),
        "torque_offset": Key("vec3", [0.0] * 3, "constant load per joint (N m, N m, N)"),
        "viscous_nonlinear": Key("vec3", [0.0] * 3, "c in c dq |dq| per joint", _nonneg3, "coefficients >= 0"),
        "hysteresis": Key("vec3", [0.0] * 3, "Dahl friction level per joint", _nonneg3, "levels >= 0"),
    },
}

SECTIONS = ("rig", "arms", "loadcell", "mocap", "object", "effects", "ros", "operator")


@dataclass
class RigConfig:
    """A validated configuration; `source` names the file (or "built-in simulated rig")."""

    source: str
    rig: dict[str, Any]
    arms: dict[str, dict[str, Any]]
    loadcell: dict[str, Any]
    mocap: dict[str, Any]
    object: dict[str, Any]
    effects: dict[str, dict[str, Any]]
    ros: dict[str, Any] = dataclasses.field(default_factory=lambda: {k: v.default for k, v in SCHEMA["ros"].items()})
    operator: dict[str, Any] = dataclasses.field(
        default_factory=lambda: {k: v.default for k, v in SCHEMA["operator"].items()})

    @property
    def simulated(self) -> bool:
        """True when every device is the simulation (the built-in rig or an all-sim file)."""
        return (all(a["driver"] == "sim" for a in self.arms.values())
                and self.loadcell["driver"] in ("sim", "none") and self.mocap["driver"] in ("sim", "none"))

    def snapshot(self) -> dict[str, Any]:
        """Plain data for a run's start record."""
        return {"source": self.source, "rig": self.rig, "arms": self.arms, "loadcell": self.loadcell,
                "mocap": self.mocap, "object": self.object, "effects": self.effects, "ros": self.ros,
                "operator": self.operator}

    def base_matrix(self, arm: str) -> np.ndarray:
        a = self.arms[arm]
        return pose_matrix(a["base_xyz"], a["base_rpy"])

    def gravity_in_base(self, arm: str) -> np.ndarray:
        """The configured world gravity in the arm's frame 0 (m/s^2)."""
        return self.base_matrix(arm)[:3, :3].T @ np.asarray(self.rig["gravity"], float)


def pose_matrix(xyz, rpy) -> np.ndarray:
    """4x4 from a position (m) and roll-pitch-yaw (rad, R = Rz(yaw) Ry(pitch) Rx(roll))."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    T = np.eye(4)
    T[:3, :3] = [[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                 [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                 [-sp, cp * sr, cp * cr]]
    T[:3, 3] = xyz
    return T


# The built-in rig: PSM2 faces PSM1 (yaw pi about z) with the tips 0.10 m apart at q0.
DEFAULT_PSM2_X = 2 * 0.4864 + 0.10


def builtin_document() -> dict[str, Any]:
    return {
        "arms": {
            "PSM1": {"driver": "sim"},
            "PSM2": {"driver": "sim", "base_xyz": [DEFAULT_PSM2_X, 0.0, 0.0], "base_rpy": [0.0, 0.0, math.pi]},
        },
    }


def _coerce(where: str, key: str, spec: Key, value: Any) -> Any:
    def bad(expected: str) -> ConfigError:
        return ConfigError(f"{where}: {key}: expected {expected}, got {value!r}")

    kind = spec.kind
    if kind == "bool":
        if not isinstance(value, bool):
            raise bad("true or false")
    elif kind == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            raise bad("an integer")
    elif kind == "float":
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise bad("a number")
        value = float(value)
        if not math.isfinite(value):
            raise bad("a finite number")
    elif kind == "str":
        if not isinstance(value, str):
            raise bad("a string")
    elif kind == "vec3":
        if (not isinstance(value, list) or len(value) != 3
                or any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in value)):
            raise bad("a list of three numbers")
        value = [float(x) for x in value]
        if not all(math.isfinite(x) for x in value):
            raise bad("three finite numbers")
    elif kind == "strlist":
        if not isinstance(value, list) or not all(isinstance(x, str) for x in value):
            raise bad("a list of strings")
    if spec.check is not None and not spec.check(value):
        raise ConfigError(f"{where}: {key}: must be {spec.allowed}, got {value!r}")
    return value


#: how the tables of each SCHEMA entry are named in rig.toml (for a key given in the wrong table)
_TABLE_OF = {"rig": "rig", "arm": "arms.<NAME>", "loadcell": "loadcell", "mocap": "mocap", "ros": "ros",
             "operator": "operator", "object": "object", "effects": "effects.<ARM>"}


def _close(word: str, choices) -> str | None:
    """The choice closest to a mistyped `word` (case ignored), or None (difflib's 0.6 cutoff)."""
    by_lower = {str(c).lower(): str(c) for c in choices}
    best = difflib.get_close_matches(str(word).lower(), list(by_lower), n=1)
    return by_lower[best[0]] if best else None


def did_you_mean(word: str, choices, prefix: str = "") -> str:
    """"; did you mean <prefix><choice>?" for the choice closest to `word`, or ""."""
    best = _close(word, choices)
    return f"; did you mean {prefix}{best}?" if best is not None else ""


def _unknown_key_hint(prefix: str, key: str, schema: dict[str, Key]) -> str:
    """Did you mean a key of this table, or this very key in another table?"""
    hint = did_you_mean(key, schema, f"{prefix}.")
    if hint:
        return hint
    tables = [_TABLE_OF[name] for name, other in SCHEMA.items() if other is not schema and key in other]
    if not tables:
        return ""
    hint = f"; {key} is a key of [{'], ['.join(tables)}]"
    if len(tables) == 1 and "<" not in tables[0]:
        hint += f": did you mean {tables[0]}.{key}?"
    return hint


def _section(where: str, prefix: str, schema: dict[str, Key], given: Any) -> dict[str, Any]:
    if not isinstance(given, dict):
        raise ConfigError(f"{where}: {prefix}: expected a table, got {given!r}")
    out = {}
    for key in given:
        if key not in schema:
            raise ConfigError(f"{where}: {prefix}.{key}: unknown key; allowed: {', '.join(schema)}"
                              + _unknown_key_hint(prefix, key, schema))
    for key, spec in schema.items():
        out[key] = _coerce(where, f"{prefix}.{key}", spec, given[key]) if key in given else copy.deepcopy(spec.default)
    return out


def parse(document: dict[str, Any], source: str) -> RigConfig:
    """Validate a parsed TOML document (missing sections take the built-in rig's values)."""
    for key in document:
        if key not in SECTIONS:
            raise ConfigError(f"{source}: {key}: unknown section; allowed: {', '.join(SECTIONS)}"
                              + did_you_mean(key, SECTIONS))
    rig = _section(source, "rig", SCHEMA["rig"], document.get("rig", {}))
    arms_doc = document.get("arms", builtin_document()["arms"])
    if not isinstance(arms_doc, dict) or not arms_doc:
        raise ConfigError(f"{source}: arms: expected at least one [arms.<NAME>] table")
    if len(arms_doc) > 3:
        raise ConfigError(f"{source}: arms: the rig drives one to three PSMs, got {len(arms_doc)}")
    arms = {name: _section(source, f"arms.{name}", SCHEMA["arm"], a) for name, a in arms_doc.items()}
    n_ros = sum(a["driver"] == "ros" for a in arms.values())
    if "rate" not in document.get("rig", {}) and n_ros:
        rig["rate"] = ROS_DEFAULT_RATE if n_ros < 3 else ROS_DEFAULT_RATE_MANY_ARMS
    ros = _section(source, "ros", SCHEMA["ros"], document.get("ros", {}))
    ros_floor = SIM_TIME_STALE_FLOOR if ros["use_sim_time"] else ROS_STALE_FLOOR
    for name, a in arms.items():
        if "watchdog" not in arms_doc[name]:
            # a ROS arm's stream comes at the console's period; a simulated one's at the rig's
            a["watchdog"] = (stale_default(ros["period"], ros_floor) if a["driver"] == "ros"
                             else stale_default(1.0 / rig["rate"], SIM_STALE_FLOOR))
    for name, a in arms.items():
        if not a["namespace"]:
            a["namespace"] = "/" + name
        if a["plant_model"]:
            a["plant_model"] = _plant_model(source, name, a)
    loadcell = _section(source, "loadcell", SCHEMA["loadcell"], document.get("loadcell", {}))
    if "stale_timeout" not in document.get("loadcell", {}):
        loadcell["stale_timeout"] = stale_default(1.0 / loadcell["rate"], SERIAL_STALE_FLOOR if loadcell["driver"]
                                                  in ("serial", "can") else SIM_STALE_FLOOR)
    if loadcell["ports"] and loadcell["driver"] != "serial":
        raise ConfigError(f"{source}: loadcell.ports: only with loadcell.driver = 'serial'")
    if loadcell["driver"] == "serial":
        # a relative port is the configuration file's folder's: the link `rig sim` makes to
        # its pty then belongs to this lab folder (a fixed /tmp name collides between two
        # users, or two rigs, of one machine), whichever folder a command runs from
        loadcell["port"] = _beside(source, loadcell["port"])
        loadcell["ports"] = [_beside(source, x) for x in loadcell["ports"]]
    if loadcell["ports"] and not loadcell["port"]:
        loadcell["port"] = loadcell["ports"][min(loadcell["element"], len(loadcell["ports"]) - 1)]
    if loadcell["driver"] == "serial" and not loadcell["port"]:
        raise ConfigError(f"{source}: loadcell.port: required when loadcell.driver = 'serial' (e.g. '/dev/ttyACM0')")
    mocap = _section(source, "mocap", SCHEMA["mocap"], document.get("mocap", {}))
    if "stale_timeout" not in document.get("mocap", {}):
        mocap["stale_timeout"] = stale_default(1.0 / mocap["rate"], (ros_floor if mocap["driver"] == "ros" else
                                                                     ROS_STALE_FLOOR) if mocap["driver"]
                                               in ("ros", "natnet") else SIM_STALE_FLOOR)
    obj = _section(source, "object", SCHEMA["object"], document.get("object", {}))
    if "arms" not in document.get("object", {}):
        obj["arms"] = list(arms)[:2] if len(arms) >= 2 else []
    for name in obj["arms"]:
        if name not in arms:
            raise ConfigError(f"{source}: object.arms: {name!r} is not an arm; arms: {', '.join(arms)}"
                              + did_you_mean(name, arms))
    if len(obj["arms"]) not in (0, 2, 3) or len(set(obj["arms"])) != len(obj["arms"]):
        raise ConfigError(f"{source}: object.arms: must name two or three different arms, got {obj['arms']}")
    if loadcell["element"] >= max(1, len(obj["arms"]) * (len(obj["arms"]) - 1) // 2):
        raise ConfigError(f"{source}: loadcell.element: the object has fewer elements than {loadcell['element'] + 1}")
    n_elements = len(obj["arms"]) * (len(obj["arms"]) - 1) // 2
    if loadcell["ports"] and len(loadcell["ports"]) != n_elements:
        raise ConfigError(f"{source}: loadcell.ports: the object ({', '.join(obj['arms'])}) has {n_elements} "
                          f"element(s), one port each; got {len(loadcell['ports'])}")
    effects_doc = document.get("effects", {})
    if not isinstance(effects_doc, dict):
        raise ConfigError(f"{source}: effects: expected tables [effects.<ARM>]")
    effects = {}
    for name, e in effects_doc.items():
        if name not in arms:
            raise ConfigError(f"{source}: effects.{name}: not an arm; arms: {', '.join(arms)}"
                              + did_you_mean(name, arms, "effects."))
        if arms[name]["driver"] != "sim":
            raise ConfigError(f"{source}: effects.{name}: hidden effects apply only to simulated arms (driver = 'sim')")
        if arms[name]["plant_model"]:
            raise ConfigError(f"{source}: effects.{name}: the arm's plant is arms.{name}.plant_model, effects "
                              "included; give one or the other")
        effects[name] = _section(source, f"effects.{name}", SCHEMA["effects"], e)
    operator = _section(source, "operator", SCHEMA["operator"], document.get("operator", {}))
    return RigConfig(source, rig, arms, loadcell, mocap, obj, effects, ros, operator)


def _beside(source: str, path: str) -> str:
    """`path` as it is when empty or absolute, else taken from the folder of the
    configuration file `source` (from the working folder for the built-in configuration)."""
    if not path or Path(path).expanduser().is_absolute() or not Path(source).is_file():
        return str(Path(path).expanduser()) if path else path
    return str(Path(source).resolve().parent / path)


def _plant_model(source: str, name: str, arm: dict) -> str:
    """The absolute path of an arm's plant model, checked now (it must load and be simulable)."""
    where = f"{source}: arms.{name}.plant_model"
    if arm["driver"] != "sim":
        raise ConfigError(f"{where}: only a simulated arm (driver = 'sim') takes a plant model")
    path = Path(arm["plant_model"]).expanduser()
    if not path.is_absolute() and Path(source).is_file():
        path = Path(source).resolve().parent / path
    try:
        return _checked_plant_model(path)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def _checked_plant_model(path: Path) -> str:
    """The absolute path of a model file that loads and maps onto a simulated plant."""
    from rig.model.model_file import ModelFileError, load_model

    path = path.resolve()
    try:
        load_model(path).plant()
    except ModelFileError as exc:
        raise ConfigError(str(exc)) from None
    return str(path)


def with_plant_model(cfg: RigConfig, path: str | Path, arms: list[str] | None = None) -> RigConfig:
    """``cfg`` with ``path`` as the plant model of ``arms`` (default: every simulated arm);
    their hidden effects, if any, give way to the model's."""
    names = arms or [n for n, a in cfg.arms.items() if a["driver"] == "sim"]
    for n in names:
        if cfg.arms[n]["driver"] != "sim":
            raise ConfigError(f"{n} is not a simulated arm (driver {cfg.arms[n]['driver']!r}): it takes no plant model")
    checked = _checked_plant_model(Path(path).expanduser())
    new_arms = copy.deepcopy(cfg.arms)
    for n in names:
        new_arms[n]["plant_model"] = checked
    effects = {k: v for k, v in cfg.effects.items() if k not in names}
    return dataclasses.replace(cfg, arms=new_arms, effects=effects)


def load(path: str | Path | None = None) -> RigConfig:
    """Load `path`, else ./rig.toml if it exists, else the built-in simulated rig."""
    if path is None:
        candidate = Path("rig.toml")
        if not candidate.exists():
            return parse({}, "built-in simulated rig")
        path = candidate
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such configuration file") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror}") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a configuration file (binary content, not TOML text)") from None
    try:
        document = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    return parse(document, str(path))

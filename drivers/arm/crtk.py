"""CRTK names and small types shared by the dVRK arm driver and its fakes.

The dVRK 2.3 PSM names its joints as below (the first three are the rig's joints 1-3);
a `Wrench` is what `body/measured_cf` carries. `StaleStream` is the error every arm
driver raises when its measured_js stream stopped (docs/safety.md, "Stale streams").

The operating state (crtk_msgs/OperatingState on `<arm>/operating_state`): `state` is one
of DISABLED, ENABLED, PAUSED, FAULT; a dVRK arm obeys motion commands (servo_jp, servo_jf,
move_jp) only when ENABLED and homed, and drops the others with a warning. Clients change it with the
`STATE_COMMANDS` on `<arm>/state_command` (crtk_msgs/StringStamped). `ArmFault` is the
error an arm driver raises when an arm it brought to ENABLED and homed leaves that state
during a run (a FAULT, a disable from the console, a pause).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rig.faults import DeviceFault, silence_text, starved_text
from rig.model import psm_kinematics as K

# dVRK PSM joint names (sensor_msgs/JointState.name), joints 1-6; the jaw is separate.
PSM_JOINT_NAMES = ("outer_yaw", "outer_pitch", "outer_insertion",
                   "outer_roll", "outer_wrist_pitch", "outer_wrist_yaw")

# A move_jp has arrived when the measured joints are this close to the goal (rad, rad, m;
# joint 3 sticks up to ~1 mm short under the PID until the integral breaks it free)...
ARRIVAL_TOLERANCE = np.array([2e-3, 2e-3, 1e-3])
# ... and slower than this (rad/s, rad/s, m/s); above the simulated velocity noise.
REST_VELOCITY = np.array([0.02, 0.02, 0.004])


class StaleStream(DeviceFault):
    """An arm's measured_js stopped arriving for longer than the watchdog interval.

    `topic` names the stream, `age` is seconds since its last message (inf if none),
    `watchdog` the limit (s), `rate_hz` the rate the arm had been publishing at (from its
    header stamps; 0: unknown), `setting` the rig.toml key of the limit (default
    `[arms.<name>] watchdog`, the name from the topic). The line says all of it, and that a
    starved process looks the same as a stopped console.
    """

    def __init__(self, topic: str, age: float, watchdog: float, *, rate_hz: float = 0.0,
                 setting: str | None = None):
        from drivers.common.ros_session import domain_text

        self.topic = topic
        self.age = age
        self.watchdog = watchdog
        self.rate_hz = rate_hz
        self.setting = setting or f"[arms.{topic.strip('/').split('/')[0]}] watchdog"
        super().__init__(f"{topic}: stale stream, {silence_text(age, rate_hz)}, beyond the {watchdog * 1e3:.0f} ms "
                         f"watchdog ({self.setting}); the driver commands the arm to hold. "
                         + starved_text(self.setting, f"the dVRK console (or `rig sim`) runs on {domain_text()}",
                                        "start it there"))


#: what <arm>/state_command accepts (crtk_msgs/StringStamped.string)
STATE_COMMANDS = ("enable", "disable", "home", "unhome", "pause", "resume")


@dataclass(frozen=True)
class OperatingState:
    """One crtk_msgs/OperatingState: `t` its header stamp (s), `state` one of
    DISABLED, ENABLED, PAUSED, FAULT; `is_homed`, `is_busy` (a move_jp or a homing under way)."""

    t: float
    state: str
    is_homed: bool
    is_busy: bool

    @property
    def ready(self) -> bool:
        """True when the arm obeys motion commands: ENABLED and homed."""
        return self.state == "ENABLED" and self.is_homed

    def describe(self) -> str:
        return (f"{self.state}, {'homed' if self.is_homed else 'not homed'}"
                + (", busy" if self.is_busy else ""))


class ArmFault(DeviceFault):
    """An arm's operating state says it no longer obeys commands (FAULT, DISABLED,
    PAUSED, not homed), or it never reached ENABLED and homed when asked.

    `topic` is the operating_state topic, `state` the OperatingState seen (None: none came),
    `reason` the arm's last error message, if it sent one.
    """

    def __init__(self, text: str, topic: str, state: OperatingState | None = None, reason: str = "",
                 arm: str | None = None):
        self.topic = topic
        self.operating_state = state
        self.reason = reason
        self.arm = arm
        # DeviceFault's structured field: the state's name ("FAULT", "DISABLED", "PAUSED",
        # "ENABLED" when it was unhomed), None when no state came
        self.state = None if state is None else state.state
        super().__init__(text)


@dataclass(frozen=True)
class Wrench:
    """A wrench: force (N) and torque (N m), expressed in `frame`, at time t (s)."""

    t: float
    force: np.ndarray
    torque: np.ndarray
    frame: str = ""


def body_wrench_from_effort(q: np.ndarray, effort: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tip force (N) in the tool-tip (body) frame that the joint efforts of joints 1-3 balance.

    Like the dVRK's body/measured_cf: f = J^-T tau with the positional Jacobian of the tip,
    rotated into the tip frame. No gravity or friction model is removed, so at rest it
    reports the weight the joints carry. The torque is zero: three joints cannot resolve it.
    Least squares keeps it finite near the RCM, where the Jacobian is singular.
    """
    q = np.asarray(q, float)[:3]
    J = K.tip_jacobian_rcm(q)
    f_rcm = np.linalg.lstsq(J.T, np.asarray(effort, float)[:3], rcond=1e-6)[0]
    R = K.tip_pose_rcm(q)[:3, :3]
    return R.T @ f_rcm, np.zeros(3)

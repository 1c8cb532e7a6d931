"""The dVRK's PSM tool definitions and the PSM's joints 1-3, as data.

Why: `rig sim` models a whole PSM with an instrument, and the numbers that decide its
kinematics (modified-DH rows), its limits, its maximum efforts and its actuator-to-joint
coupling are the dVRK's own. They are transcribed here once, so the kinematics
(rig.model.psm_arm_kinematics) and the wrist model (rig.model.wrist_plant) read the same facts and a
reader can check them against the source line by line. No code of the dVRK is copied.

Source: github.com/jhu-dvrk/sawIntuitiveResearchKit, commit 9e535e68eb7f (2026-04-17;
the tool and kinematic files last changed in b37c435f0a80, 2025-09-02):

* share/kinematic/PSM.json           joints 1-3 (yaw, pitch, insertion): PSM_DH, limits, ftmax
* share/tool/<NAME>.json              joints 4-6 DH rows, "jaw" limits and ftmax,
                                      "tooltip_offset", "coupling" ActuatorToJointPosition,
                                      "tool_engage_position"
* share/tool/index.json               the descriptions and the file of each model number
* core/components/include/sawIntuitiveResearchKit/mtsIntuitiveResearchKit.h
                                      SAFE_DISTANCE_FROM_RCM, DISK_MAX_TORQUE, ...
* core/applications/io-config-generator/dvrk-io-config-generator.py (ClassicPSM)
                                      the wrist actuators' encoder, gear and motor numbers
* share/pid/sawControllersPID-PSM.json
                                      the PID gains of the four wrist actuators

Conventions, as in the dVRK's files: modified (Craig) DH, one row per joint, the link
transform Rx(alpha) Tx(a) Rz(theta) Tz(d), with theta = q + offset for a revolute joint
and d = q + offset for the prismatic one (the file's "theta" and "D" are then constant
parts, 0 for theta throughout). The files write pi/2 as 1.5708; the values are kept as
written (rig.model.psm_arm_kinematics decides what to do with them). Joint order of a tool's
4-vectors (coupling, engage positions): roll, wrist pitch, wrist yaw, jaw.

`coupling` maps actuator (sterile-adapter disc) positions to joint positions,
q = C a (rad). The dVRK derives the rest from it (prmActuatorJointCouplingCheck.cpp):
JointToActuatorPosition = C^-1, ActuatorToJointEffort = C^-T (so that power is the same
on both sides), JointToActuatorEffort = C^T.

Tools: the default large needle driver 400006 and seven other classic instruments with
one DH row per wrist joint. NEEDLE_DRIVER_400117 (the 5 mm needle driver) exists in the
dVRK but is "snake-like": five DH rows for four wrist joints and a different coupling,
which a 3-row `Tool` cannot hold, so it is left out (as is MARYLAND_DISSECTOR_400143).

Units: m, rad, N, N m.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DVRK_COMMIT = "9e535e68eb7ff276d0516142bde82474fe9dc4bf"


@dataclass(frozen=True)
class DHRow:
    """One modified-DH row of the dVRK: Rx(alpha) Tx(a) Rz(theta) Tz(d) (rad, m)."""

    name: str
    alpha: float
    a: float
    theta: float
    d: float
    offset: float
    revolute: bool = True


# share/kinematic/PSM.json: yaw, pitch, insertion.
PSM_DH: tuple[DHRow, DHRow, DHRow] = (
    DHRow("yaw", alpha=1.5708, a=0.0, theta=0.0, d=0.0, offset=1.5708),
    DHRow("pitch", alpha=-1.5708, a=0.0, theta=0.0, d=0.0, offset=-1.5708),
    DHRow("insertion", alpha=1.5708, a=0.0, theta=0.0, d=0.0, offset=-0.4318, revolute=False),
)
PSM_Q_MIN = (-1.588, -0.925025, 0.0)        # rad, rad, m
PSM_Q_MAX = (1.588, 0.925025, 0.24)         # rad, rad, m

# mtsIntuitiveResearchKit.h, namespace PSM.
SAFE_DISTANCE_FROM_RCM = 0.045       # m: the shaft end (frame 4) is kept this far from the RCM
SAFE_DISTANCE_FROM_RCM_BUFFER = 0.002  # m
DISK_MAX_TORQUE = 0.343642           # N m at a sterile-adapter disc

# dvrk-io-config-generator.py, ClassicPSM, actuators 4-7 (the four discs).
WRIST_ENCODER_CPT = 4000             # counts per motor turn
WRIST_GEAR_RATIO = 11.71             # motor turns per disc turn
# 0.67 A * 0.0438 N m/A * 11.71 = 0.3436 N m: DISK_MAX_TORQUE above.

# share/pid/sawControllersPID-PSM.json, indices 3-6 ("disc_1" .. "disc_4"): the PID of the
# wrist runs on the discs (actuator space), i_gain 0, "pid_max_output" disabled.
WRIST_PID_P_GAIN = (6.0, 6.0, 6.0, 6.0)      # N m / rad
WRIST_PID_D_GAIN = (0.09, 0.09, 0.09, 0.09)  # N m s / rad
WRIST_PID_TOLERANCE = (0.6, 0.6, 0.6, 0.6)   # rad: "p_measured_setpoint_tolerance"


@dataclass(frozen=True)
class Tool:
    """One dVRK instrument: joints 4-6 and the jaw, as in share/tool/<name>.json.

    Tuples keep the dataclass hashable and immutable; the `*_matrix` properties give numpy
    copies. Limits and efforts are for (roll, wrist pitch, wrist yaw) in rad and N m.
    """

    name: str
    description: str
    dh: tuple[DHRow, DHRow, DHRow]
    q_min: tuple[float, float, float]
    q_max: tuple[float, float, float]
    effort_max: tuple[float, float, float]
    jaw_min: float
    jaw_max: float
    jaw_effort_max: float
    tooltip_offset: tuple[tuple[float, ...], ...]
    coupling: tuple[tuple[float, ...], ...]
    tool_engage_lower: tuple[float, float, float, float]
    tool_engage_upper: tuple[float, float, float, float]

    @property
    def tooltip_offset_matrix(self) -> np.ndarray:
        """4x4 transform from the last DH frame to the tool tip."""
        return np.array(self.tooltip_offset, dtype=float)

    @property
    def coupling_matrix(self) -> np.ndarray:
        """4x4 ActuatorToJointPosition C: q = C a for [roll, pitch, yaw, jaw]."""
        return np.array(self.coupling, dtype=float)

    @property
    def q4_min(self) -> np.ndarray:
        """Software lower limits of [roll, wrist pitch, wrist yaw, jaw] (rad)."""
        return np.array(self.q_min + (self.jaw_min,))

    @property
    def q4_max(self) -> np.ndarray:
        """Software upper limits of [roll, wrist pitch, wrist yaw, jaw] (rad)."""
        return np.array(self.q_max + (self.jaw_max,))

    @property
    def effort4_max(self) -> np.ndarray:
        """ftmax of [roll, wrist pitch, wrist yaw, jaw] (N m)."""
        return np.array(self.effort_max + (self.jaw_effort_max,))

    @property
    def wrist_yaw_length(self) -> float:
        """Distance from the wrist-pitch axis to the wrist-yaw axis, the wrist_yaw row's A (m)."""
        return self.dh[2].a


TOOLS: tuple[Tool, ...] = (
    Tool(
        name="LARGE_NEEDLE_DRIVER_400006",
        description="Large Needle Driver",
        dh=(
            DHRow("roll", alpha=0.0, a=0.0, theta=0.0, d=0.4162, offset=0.0),
            DHRow("wrist_pitch", alpha=-1.5708, a=0.0, theta=0.0, d=0.0, offset=-1.5708),
            DHRow("wrist_yaw", alpha=-1.5708, a=0.0091, theta=0.0, d=0.0, offset=-1.5708),
        ),
        q_min=(-4.53786, -1.39626, -1.39626),
        q_max=(4.53786, 1.39626, 1.39626),
        effort_max=(0.33, 0.25, 0.2),
        jaw_min=-0.698132, jaw_max=1.39626, jaw_effort_max=0.16,
        tooltip_offset=(
            (0.0, -1.0, 0.0, 0.0),
            (0.0, 0.0, 1.0, 0.0),
            (-1.0, 0.0, 0.0, 0.0),
            (0.0, 0.0, 0.0, 1.0),
        ),
        coupling=(
            (-1.5632, 0.0, 0.0, 0.0),
            (0.0, 1.0186, 0.0, 0.0),
            (0.0, -0.8306, 0.6089, 0.6089),
            (0.0, 0.0, -1.2177, 1.2177),
        ),
        tool_engage_lower=(-4.5378, -0.261799, -0.261799, 0.0),
        tool_engage_upper=(4.5378, 0.261799, 0.261799, 0.0),
    ),
    Tool(
        name="PROGRASP_FORCEPS_400093",
        description="Prograsp Forceps",
        dh=(
            DHRow("roll", alpha=0.0, a=0.0, theta=0.0, d=0.4162, offset=0.0),
            DHRow("wrist_pitch", alpha=-1.5708, a=0.0, theta=0.0, d=0.0, offset=-1.5708),
            DHRow("wrist_yaw", alpha=-1.5708, a=0.0107, theta=0.0, d=0.0, offset=-1.5708),
        ),
        q_min=(-4.53786, -1.39626, -1.39626),
        q_max=(4.53786, 1.39626, 1.39626),
        effort_max=(0.33, 0.25, 0.2),
        jaw_min=-0.349066, jaw_max=1.39626, jaw_effort_max=0.16,
        tooltip_offset=(
            (0.0, -1.0, 0.0, 0.0),
            (0.0, 0.0, 1.0, 0.0),
            (-1.0, 0.0, 0.0, 0.0),
            (0.0, 0.0, 0.0, 1.0),
        ),
        coupling=(
            (-1.5631, 0.0, 0.0, 0.0),
            (0.0, 1.0, 0.0, 0.0),
            (0.0, -0.5068, -0.5135, -0.5135),
            (0.0, 0.0, -0.5279, 0.5279),
        ),
        tool_engage_lower=(-4.5378, -0.174533, -0.174533, 0.0),
        tool_engage_upper=(4.5378, 0.174533, 0.174533, 0.0),
    ),
    Tool(
        name="CURVED_SCISSORS_400178",
        description="Curved Scissors",
        dh=(
            DHRow("roll", alpha=0.0, a=0.0, theta=0.0, d=0.4162, offset=0.0),
            DHRow("wrist_pitch", alpha=-1.5708, a=0.0, theta=0.0, d=0.0, offset=-1.5708),
            DHRow("wrist_yaw", alpha=-1.5708, a=0.0091, theta=0.0, d=0.0, offset=-1.5708),
        ),
        q_min=(-4.53786, -1.39626, -1.39626),
        q_max=(4.53786, 1.39626, 1.39626),
        effort_max=(0.33, 0.25, 0.2),
        jaw_min=-0.349066, jaw_max=1.39626, jaw_effort_max=0.16,
        tooltip_offset=(
            (0.0, -1.0, 0.0, 0.0),
            (0.0, 0.0, 1.0, 0.0),
            (-1.0, 0.0, 0.0, 0.0),
            (0.0, 0.0, 0.0, 1.0),
        ),
        coupling=(
            (-1.5632, 0.0, 0.0, 0.0),
            (0.0, 1.0186, 0.0, 0.0),
            (0.0, -0.8306, 0.6089, 0.6089),
            (0.0, 0.0, -1.2177, 1.2177),
        ),
        tool_engage_lower=(-4.5378, -0.261799, -0.261799, 0.0),
        tool_engage_upper=(4.5378, 0.261799, 0.261799, 0.0),
    ),
    Tool(
        name="MARYLAND_BIPOLAR_FORCEPS_400172",
        description="Maryland Bipolar Forceps",
        dh=(
            DHRow("roll", alpha=0.0, a=0.0, theta=0.0, d=0.4162, offset=0.0),
            DHRow("wrist_pitch", alpha=-1.5708, a=0.0, theta=0.0, d=0.0, offset=-1.5708),
            DHRow("wrist_yaw", alpha=-1.5708, a=0.0107, theta=0.0, d=0.0, offset=-1.5708),
        ),
        q_min=(-4.4506, -1.2217, -1.5708),
        q_max=(4.4506, 1.2217, 1.5708),
        effort_max=(0.33, 0.25, 0.2),
        jaw_min=-0.349066, jaw_max=1.39626, jaw_effort_max=0.19,
        tooltip_offset=(
            (0.0, -1.0, 0.0, 0.0),
            (0.0, 0.0, 1.0, 0.0),
            (-1.0, 0.0, 0.0, 0.0),
            (0.0, 0.0, 0.0, 1.0),
        ),
        coupling=(
            (-1.563233, 0.0, 0.0, 0.0),
            (0.0, 1.0, 0.0, 0.0),
            (0.0, -0.630273, 0.457982, 0.457982),
            (0.0, 0.0, -0.915964, 0.915964),
        ),
        tool_engage_lower=(-4.5378, -0.174533, -0.174533, 0.0),
        tool_engage_upper=(4.5378, 0.174533, 0.174533, 0.0),
    ),
    Tool(
        name="MEGA_NEEDLE_DRIVER_400194",
        description="Mega Needle Driver",
        dh=(
            DHRow("roll", alpha=0.0, a=0.0, theta=0.0, d=0.4162, offset=0.0),
            DHRow("wrist_pitch", alpha=-1.5708, a=0.0, theta=0.0, d=0.0, offset=-1.5708),
            DHRow("wrist_yaw", alpha=-1.5708, a=0.0112, theta=0.0, d=0.0, offset=-1.5708),
        ),
        q_min=(-4.4506, -1.2217, -1.39626),
        q_max=(4.4506, 1.2217, 1.39626),
        effort_max=(0.33, 0.25, 0.2),
        jaw_min=-0.349066, jaw_max=1.39626, jaw_effort_max=0.19,
        tooltip_offset=(
            (0.0, -1.0, 0.0, 0.0),
            (0.0, 0.0, 1.0, 0.0),
            (-1.0, 0.0, 0.0, 0.0),
            (0.0, 0.0, 0.0, 1.0),
        ),
        coupling=(
            (-1.5575, 0.0, 0.0, 0.0),
            (0.0, 1.0, 0.0, 0.0),
            (0.0, -0.456081, 0.368243, 0.368243),
            (0.0, 0.0, -0.736486, 0.736486),
        ),
        tool_engage_lower=(-4.5378, -0.174533, -0.174533, 0.0),
        tool_engage_upper=(4.5378, 0.174533, 0.174533, 0.0),
    ),
    Tool(
        name="CADIERE_FORCEPS_400049",
        description="Cadiere Forceps",
        dh=(
            DHRow("roll", alpha=0.0, a=0.0, theta=0.0, d=0.4162, offset=0.0),
            DHRow("wrist_pitch", alpha=-1.5708, a=0.0, theta=0.0, d=0.0, offset=-1.5708),
            DHRow("wrist_yaw", alpha=-1.5708, a=0.0091, theta=0.0, d=0.0, offset=-1.5708),
        ),
        q_min=(-4.53786, -1.39626, -1.39626),
        q_max=(4.53786, 1.39626, 1.39626),
        effort_max=(0.33, 0.25, 0.2),
        jaw_min=-0.349066, jaw_max=1.39626, jaw_effort_max=0.16,
        tooltip_offset=(
            (0.0, -1.0, 0.0, 0.0),
            (0.0, 0.0, 1.0, 0.0),
            (-1.0, 0.0, 0.0, 0.0),
            (0.0, 0.0, 0.0, 1.0),
        ),
        coupling=(
            (-1.5632, 0.0, 0.0, 0.0),
            (0.0, 1.0186, 0.0, 0.0),
            (0.0, -0.8306, 0.6089, 0.6089),
            (0.0, 0.0, -1.2177, 1.2177),
        ),
        tool_engage_lower=(-4.5378, -0.174533, -0.174533, 0.0),
        tool_engage_upper=(4.5378, 0.174533, 0.174533, 0.0),
    ),
    Tool(
        name="DEBAKEY_FORCEPS_400036",
        description="DeBakey Forceps",
        dh=(
            DHRow("roll", alpha=0.0, a=0.0, theta=0.0, d=0.4162, offset=0.0),
            DHRow("wrist_pitch", alpha=-1.5708, a=0.0, theta=0.0, d=0.0, offset=-1.5708),
            DHRow("wrist_yaw", alpha=-1.5708, a=0.0091, theta=0.0, d=0.0, offset=-1.5708),
        ),
        q_min=(-4.53786, -1.39626, -1.39626),
        q_max=(4.53786, 1.39626, 1.39626),
        effort_max=(0.33, 0.25, 0.2),
        jaw_min=-0.349066, jaw_max=1.39626, jaw_effort_max=0.16,
        tooltip_offset=(
            (0.0, -1.0, 0.0, 0.0),
            (0.0, 0.0, 1.0, 0.0),
            (-1.0, 0.0, 0.0, 0.0),
            (0.0, 0.0, 0.0, 1.0),
        ),
        coupling=(
            (-1.5632, 0.0, 0.0, 0.0),
            (0.0, 1.0186, 0.0, 0.0),
            (0.0, -0.8306, 0.6089, 0.6089),
            (0.0, 0.0, -1.2177, 1.2177),
        ),
        tool_engage_lower=(-4.5378, -0.261799, -0.261799, 0.0),
        tool_engage_upper=(4.5378, 0.261799, 0.261799, 0.0),
    ),
    Tool(
        name="MONOPOLAR_CURVED_SCISSORS_400179",
        description="Monopolar Curved Scissors",
        dh=(
            DHRow("roll", alpha=0.0, a=0.0, theta=0.0, d=0.4162, offset=0.0),
            DHRow("wrist_pitch", alpha=-1.5708, a=0.0, theta=0.0, d=0.0, offset=-1.5708),
            DHRow("wrist_yaw", alpha=-1.5708, a=0.0091, theta=0.0, d=0.0, offset=-1.5708),
        ),
        q_min=(-4.53786, -1.39626, -1.39626),
        q_max=(4.53786, 1.39626, 1.39626),
        effort_max=(0.33, 0.25, 0.2),
        jaw_min=-0.349066, jaw_max=1.39626, jaw_effort_max=0.16,
        tooltip_offset=(
            (0.0, -1.0, 0.0, 0.0),
            (0.0, 0.0, 1.0, 0.0),
            (-1.0, 0.0, 0.0, 0.0),
            (0.0, 0.0, 0.0, 1.0),
        ),
        coupling=(
            (-1.5632, 0.0, 0.0, 0.0),
            (0.0, 1.0186, 0.0, 0.0),
            (0.0, -0.8306, 0.6089, 0.6089),
            (0.0, 0.0, -1.2177, 1.2177),
        ),
        tool_engage_lower=(-4.5378, -0.261799, -0.261799, 0.0),
        tool_engage_upper=(4.5378, 0.261799, 0.261799, 0.0),
    ),
)

_BY_NAME = {t.name: t for t in TOOLS}
DEFAULT_TOOL = _BY_NAME["LARGE_NEEDLE_DRIVER_400006"]
TOOL_NAMES = tuple(_BY_NAME)


def tool(name: str) -> Tool:
    """The tool called `name`, e.g. "LARGE_NEEDLE_DRIVER_400006" (the dVRK's own spelling
    "LARGE_NEEDLE_DRIVER:400006" is taken too); ValueError naming the known ones otherwise."""
    key = name.strip().upper().replace(":", "_")
    try:
        return _BY_NAME[key]
    except KeyError:
        raise ValueError(f"unknown tool {name!r}; known tools: {', '.join(TOOL_NAMES)}") from None

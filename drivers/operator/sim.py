"""The simulated operator: what a person does by hand on the real rig, done by the simulation.

`SimOperator` is the in-process twin of the operator, on the simulated world a procedure
drives itself; `rig sim` serves the same on the side channel of `drivers.operator.driver`
through `drivers.operator.fake_operator_server.FakeOperatorServer`, so that a procedure in
another process (`RosOperator`) gets its manual steps done unattended.

The actions (drivers.operator.driver.ACTIONS): markers are mounted by construction, so confirm
does nothing; detach/attach take the object off the tool tips or put it back; hang_mass
loads a load cell with the weight of a mass instead of the object's tension (0 kg: an
empty cell); touch puts every named arm's tool tip (wrist straight) on a world point by inverse kinematics on
the *true* arm placement (what a person guiding the tips together achieves physically,
whatever the calibration believes) and holds it there; unplug pulls the load cell's cable
(a fault for tests: its pty closes); fault injects an arm fault for tests (`joint_limit`:
the person pushes a joint of the arm past its upper limit, which a powered arm's limit
check faults on; `servo_watchdog`: the arm's watchdog on servo commands is armed with a
timeout, or disarmed with 0), on the arms `rig sim` serves behind their operating state
(`drivers.arm.fake_arm_state`).
"""

from __future__ import annotations

import numpy as np

from drivers.loadcell.force_calibration import STANDARD_GRAVITY
from drivers.operator.driver import OperatorError, check_mass


#: N/m, the thesis's objects: the compliant spring and the stiff suture string
OBJECT_STIFFNESS = {"spring": 2450.0, "string": 20000.0}


class CellLoad:
    """What pulls on a simulated load cell: the object's tension on `element`, or, once a
    mass hangs from it, that mass's weight (N). `sink(newtons)`, if given, is where
    `update()` delivers it (the firmware process's shared tension); `pump`, if given, is
    called by `update()` too (a firmware stepped on simulated time, which reads the tension
    itself); `cable`, if given, is pulled by the operator's unplug."""

    def __init__(self, world, element: int = 0, sink=None, cable=None, pump=None):
        self.world = world
        self.element = element
        self.kg: float | None = None
        self.sink = sink
        self.cable = cable
        self.pump = pump

    def update(self) -> None:
        if self.sink is not None:
            self.sink(self())
        if self.pump is not None:
            self.pump()

    def __call__(self) -> float:
        if self.kg is not None:
            return self.kg * STANDARD_GRAVITY
        world = self.world
        return world.tension(self.element) if self.element < len(world.object_elements) else 0.0


class SimOperator:
    """The operator of the in-process simulated rig (see the module docstring).

    world: the SimWorld; arms: name -> SimArm (for touch's hold); cell: the CellLoad of
    the load cell masses hang from (None: no cell to hang them on); object_spec: what
    attach_object attaches (default: the object the world was built with).
    """

    def __init__(self, world, arms: dict | None = None, cell: CellLoad | None = None, object_spec=None,
                 cells: dict[int, CellLoad] | None = None, states: dict | None = None):
        self.world = world
        self.arms = arms or {}
        self.states = states or {}  # arm -> drivers.arm.fake_arm_state.FakeArmState (rig sim's arms)
        self.cell = cell
        # element -> its cell, where the rig has a cell per object element
        self.cells = dict(cells) if cells else ({cell.element: cell} if cell is not None else {})
        self.object_spec = object_spec if object_spec is not None else world.object
        self.pinned: dict[str, np.ndarray] = {}  # arm -> joints where a touch holds its tip
        #: other cables a person can pull: "mocap" (the tracker's stream stops), "operator"
        #: (the person walks away: requests go unanswered), each a callable set by its server
        self.cables: dict[str, object] = {}

    def confirm(self, message: str) -> None:
        return None

    def detach_object(self) -> None:
        self.world.detach_object()

    def attach_object(self, kind: str | None = None) -> None:
        import dataclasses

        spec = self.object_spec
        if spec is None:
            raise OperatorError("the simulated rig has no object to attach")
        if kind is not None and kind != spec.kind:
            if kind not in OBJECT_STIFFNESS:
                raise OperatorError(f"no simulated object {kind!r}; objects: {', '.join(OBJECT_STIFFNESS)}")
            spec = dataclasses.replace(spec, kind=kind, stiffness=OBJECT_STIFFNESS[kind])
        current = self.world.object
        if current is None or current.kind != spec.kind:
            if current is not None:
                self.world.detach_object()
            self.world.attach_object(spec)
        for cell in self.cells.values():
            cell.kg = None

    def hang_mass(self, kg: float, element: int | None = None) -> None:
        check_mass(kg)
        cell = self.cell if element is None else self.cells.get(int(element))
        if cell is None:
            raise OperatorError("the simulated rig serves no load cell to hang a mass from"
                                + ("" if element is None else f" on element {element}; it serves "
                                   f"{sorted(self.cells) or 'none'}"))
        cell.kg = float(kg)
        # the mass hangs when the person says so: the cell feels it now, not at the world's
        # next step (on a loaded machine rig sim's loop runs late, and a calibration that
        # starts averaging on the reply would mix in the old load)
        cell.update()

    def unplug(self, device: str) -> None:
        """Pull a cable out (a fault a person can cause): "loadcell" (its pty closes),
        "mocap" (the tracker stops streaming), "operator" (the person leaves: this reply
        is the last)."""
        if device == "loadcell":
            if self.cell is None or self.cell.cable is None:
                raise OperatorError("the simulated rig serves no load cell to unplug")
            self.cell.cable()
            return
        cable = self.cables.get(device)
        if cable is None:
            known = ["loadcell", *self.cables]
            raise OperatorError(f"can only unplug {', '.join(repr(k) for k in known)} here, not {device!r}")
        cable()

    def fault(self, arm: str, kind: str, joint: int = 1, timeout: float = 0.1) -> None:
        """Inject an arm fault (tests): "joint_limit" pushes `joint` (1-3) past its upper
        limit (at once: with an object between the arms its pull can fault the other arm
        too); "power_loss" takes the power from the arm's amplifiers where it stands (the
        dVRK's "detected power loss (actuators)", e.g. an amplifier's fault or its controller's
        e-stop); "servo_watchdog" arms the servo-command watchdog with `timeout` s (0: off)."""
        state = self.states.get(arm)
        if state is None:
            raise OperatorError(f"no arm {arm!r} behind an operating state here; "
                                f"arms: {', '.join(self.states) or 'none (in-process arms have none)'}")
        if kind == "joint_limit":
            if joint not in (1, 2, 3):
                raise OperatorError(f"joint must be 1, 2 or 3, got {joint!r}")
            self.release(arm)  # a person pushing the joint no longer holds the tip on a touch point
            state.push_past_limit(joint)
        elif kind == "power_loss":
            state.lose_power()
        elif kind == "servo_watchdog":
            if not (np.isfinite(timeout) and timeout >= 0):
                raise OperatorError(f"the watchdog timeout must be >= 0 s (0: off), got {timeout!r}")
            state.servo_watchdog = float(timeout) if timeout > 0 else None
        else:
            raise OperatorError(f"unknown fault {kind!r}; known: joint_limit, power_loss, servo_watchdog")

    def touch(self, arms, point_index: int, goal_world) -> None:
        from rig.model import psm_kinematics as K

        goal = np.asarray(goal_world, float)
        if goal.shape != (3,) or not np.all(np.isfinite(goal)):
            raise OperatorError(f"a touch point is three finite coordinates (m), got {goal_world!r}")
        for name in arms:
            if name not in self.world.arms:
                raise OperatorError(f"no simulated arm {name!r}; arms: {', '.join(self.world.arms)}")
        from rig.model.psm_tool import DEFAULT_TOOL

        for name in arms:
            T = np.linalg.inv(self.world.arms[name].rcm_world)
            # a person brings the tool tips together: with the wrist straight the tool tip is
            # the tool's wrist-yaw length beyond the shaft end, along the shaft (through the RCM)
            p = (T @ np.append(goal, 1.0))[:3]
            q = K.ik_rcm(p * (1.0 - DEFAULT_TOOL.wrist_yaw_length / float(np.linalg.norm(p))))
            self.world.set_state(name, q)
            arm = self.arms.get(name) if isinstance(arms, (list, tuple)) else arms[name]
            if arm is not None:
                arm.hold()
            self.pinned[name] = q

    def hold_touch(self) -> None:
        """Keep touching tips where the person holds them, step after step: left to the
        arm's PID alone they would sag under gravity before a client in another process
        reads them. `FakeOperatorServer` calls it every step until the next request or a
        command to the arm."""
        for name, q in self.pinned.items():
            self.world.set_state(name, q)

    def release(self, name: str | None = None) -> None:
        """Let go of one arm's tip (a command to it arrived), or of all."""
        if name is None:
            self.pinned.clear()
        else:
            self.pinned.pop(name, None)

"""What the dVRK arm driver (drivers.arm.dvrk_arm.RosArm) hears: its executor's callbacks for the
arm's streams and operating state, the watchdog that judges measured_js stale, and the
reading side of the Arm interface (measured_js, drain_js, setpoint_js, measured_cp, ...).
A mixin of RosArm: the state it reads is made in RosArm.__init__. Units: SI; times are
seconds on the driver's time base."""

from __future__ import annotations

import time
from typing import Callable

import numpy as np

from drivers.common import cdr
from drivers.arm.crtk import ArmFault, OperatingState, StaleStream, Wrench
from drivers.interfaces import JointState, Pose
from drivers.common.quaternion import quat_xyzw_to_matrix

StaleCallback = Callable[[StaleStream], None]

#: the names of joints 1-3 in a dVRK PSM's measured_js: 2.x's, and the bare ones of some
#: configurations
_MODEL_JOINTS = (("outer_yaw", "yaw"), ("outer_pitch", "pitch"), ("outer_insertion", "insertion"))


def _stamp_seconds(header) -> float:
    return header.stamp.sec + header.stamp.nanosec * 1e-9


class ArmStreams:
    """RosArm's streams, watchdog and reading (see the module docstring)."""

    # -- executor thread ----------------------------------------------------------------
    def _spin(self) -> None:
        try:
            self._executor.spin()
        except Exception:  # noqa: BLE001 - context shut down under us while closing
            if not self._closing.is_set():
                raise

    @staticmethod
    def _joint_state(m) -> JointState:
        return JointState(_stamp_seconds(m.header), np.array(m.position, float), np.array(m.velocity, float),
                          np.array(m.effort, float), tuple(m.name))

    @staticmethod
    def _pose(m) -> Pose:
        p, o = m.pose.position, m.pose.orientation
        # geometry_msgs/Quaternion is (x, y, z, w), scalar last.
        R = quat_xyzw_to_matrix(np.array([o.x, o.y, o.z, o.w], float))
        return Pose(_stamp_seconds(m.header), np.array([p.x, p.y, p.z]), R, m.header.frame_id)

    @staticmethod
    def _wrench(m) -> Wrench:
        f, tq = m.wrench.force, m.wrench.torque
        return Wrench(_stamp_seconds(m.header), np.array([f.x, f.y, f.z]), np.array([tq.x, tq.y, tq.z]),
                      m.header.frame_id)

    def _map(self, names: tuple[str, ...], n: int) -> tuple[int, ...]:
        """Indices of joints 1-3 in a message with `names` (n values), found once per naming."""
        if names != self._names or self._index is None:
            index = []
            for options in _MODEL_JOINTS:
                found = next((names.index(o) for o in options if o in names), None)
                index.append(found)
            if None in index:
                index = list(range(min(3, n)))  # no names, or other ones: by position
            self._index, self._names = tuple(index), names
            self.joint_count = n
        return self._index

    def _model_joints(self, full: JointState) -> JointState:
        """Joints 1-3 of a message of the whole arm (found by name, see the module docstring)."""
        n = len(full.position)
        idx = self._map(full.name, n)
        if n <= 3 and idx == (0, 1, 2):
            return full

        def pick(v):
            return v[list(idx)] if len(v) == n else v[:3]
        return JointState(full.t, pick(full.position), pick(full.velocity), pick(full.effort),
                          tuple(full.name[i] for i in idx) if full.name else ())

    def _on_measured_js(self, raw: bytes) -> None:
        try:
            t_ns, _, names, position, velocity, effort = cdr.joint_state(raw)
        except cdr.CdrError:
            with self._lock:
                self.malformed += 1
            return
        full = JointState(t_ns * 1e-9, np.array(position, float), np.array(velocity, float),
                          np.array(effort, float), names)
        js = self._model_joints(full)
        with self._cond:
            self._stamps.append(full.t)
            self._full = (full.position, full.velocity)
            self._js = js
            self._js_log.append(js)
            self._js_rx = self._time.now()
            self._stale_fired = False
            self.received += 1
            self._cond.notify_all()
        self._time.notify()

    def _store(self, key: str, value) -> None:
        with self._lock:
            self._latest[key] = value

    def _on_operating_state(self, m) -> None:
        st = OperatingState(_stamp_seconds(m.header), str(m.state), bool(m.is_homed), bool(m.is_busy))
        with self._cond:
            self._state = st
            self._state_count += 1
            if st.is_busy:
                self._busy_index = self._state_count
            else:
                self._idle_index = self._state_count
            if self._in_control and self._fault is None and not st.ready:
                self._fault = st
            self._cond.notify_all()

    def _on_error(self, m) -> None:
        with self._cond:
            self._error = (self._time.now(), str(m.data))
            self._cond.notify_all()

    # -- watchdog thread ----------------------------------------------------------------
    def _watch(self) -> None:
        while not self._closing.wait(self.watchdog / 5.0):
            with self._lock:
                rx, fired, js = self._js_rx, self._stale_fired, self._js
            if rx is None or fired:
                continue  # not armed before the first sample; once per outage
            age = self._age(rx)
            err = self._time.stalled()  # on simulated time: the clock itself stopped
            if age <= self.watchdog and err is None:
                continue
            with self._lock:
                self._stale_fired = True
            self.stale_events += 1
            err = err or self._stale(age)
            try:
                with self._lock:
                    full = self._full
                self._publish("servo_jp", position=full[0] if full is not None else js.position)
            except Exception:  # noqa: BLE001 - a dead context must not stop the callbacks
                pass
            for cb in list(self._stale_callbacks):
                try:
                    cb(err)
                except Exception as exc:  # noqa: BLE001 - report, and still call the others
                    self.node.get_logger().error(f"{self.name}: stale callback failed: {exc}")

    def _stale(self, age: float) -> StaleStream:
        """The StaleStream of measured_js `age` s old: with the rate the arm had been
        publishing at and the rig.toml key of the watchdog."""
        return StaleStream(self.topic["measured_js"], age, self.watchdog, rate_hz=self.published_rate(),
                           setting=self.setting)

    def _age(self, rx: float) -> float:
        """Seconds the executor has been looking for measured_js since the last one came (on
        simulated time: simulated seconds since it came, which a starved process never adds)."""
        now = self._time.now()
        if self._polled is not None and not self._time.simulated:
            now = min(now, self._polled())
        return max(0.0, now - rx)

    def add_stale_callback(self, fn: StaleCallback) -> None:
        """Call `fn(StaleStream)` from the watchdog thread when measured_js goes stale."""
        self._stale_callbacks.append(fn)

    # -- reading ------------------------------------------------------------------------
    def published_rate(self) -> float:
        """Hz at which the arm publishes measured_js, from the header stamps of the newest
        messages (the median interval): what the console sends, whatever delays this
        process's reading of them (0.0 before two messages)."""
        with self._lock:
            t = np.array(self._stamps)
        d = np.diff(t)
        d = d[d > 0]
        return float(1.0 / np.median(d)) if d.size else 0.0

    def stream_age(self) -> float:
        """Seconds since the last measured_js (inf before the first)."""
        with self._lock:
            rx = self._js_rx
        return float("inf") if rx is None else self._age(rx)

    def wait_for_data(self, timeout: float = 5.0) -> bool:
        """Block until a measured_js arrived (True) or `timeout` s passed (False)."""
        tb = self._time
        deadline = tb.now() + timeout
        with self._cond:
            while self._js is None:
                left = deadline - tb.now()
                if left <= 0:
                    return False
                tb.wait(self._cond, left)
        return True

    def wait_newer(self, count: int, timeout: float) -> bool:
        """Block until more than `count` measured_js have arrived (True) or `timeout` s passed."""
        tb = self._time
        deadline = tb.now() + timeout
        with self._cond:
            while self.received <= count:
                left = deadline - tb.now()
                if left <= 0:
                    return False
                tb.wait(self._cond, left)
        return True

    def last_stamp(self) -> float:
        """The header stamp (s) of the newest measured_js (-inf before the first)."""
        with self._lock:
            return self._stamps[-1] if self._stamps else float("-inf")

    def measured_js(self) -> JointState:
        """The newest measured joint state, every joint the message carries.

        Raises StaleStream if none arrived within the watchdog interval, ArmFault once the
        arm left ENABLED and homed after `ready()`.
        """
        with self._lock:
            js, rx, fault = self._js, self._js_rx, self._fault
        if fault is not None:
            raise self._fault_raised(fault)
        self._time.check()
        age = float("inf") if rx is None else self._age(rx)
        if js is None or age > self.watchdog:
            raise self._stale(age)
        return js

    def drain_js(self) -> list[JointState]:
        """Every measured_js received since the last drain, oldest first (the newest 4096 at
        most); StaleStream and ArmFault as measured_js()."""
        self.measured_js()
        with self._lock:
            out = list(self._js_log)
            self._js_log.clear()
        return out

    def _get(self, key: str):
        if key not in self.streams:
            raise RuntimeError(f"{self.topic[key]}: not subscribed (RosArm streams={self.streams})")
        with self._lock:
            value = self._latest.get(key)
        if value is None:
            raise RuntimeError(f"{self.topic[key]}: no message received yet")
        return value

    def setpoint_js(self) -> JointState:
        return self._get("setpoint_js")

    def measured_cp(self) -> Pose:
        """Newest tool-tip pose (dVRK measured_cp: RCM frame unless a base frame is set)."""
        return self._get("measured_cp")

    def local_measured_cp(self) -> Pose:
        return self._get("local/measured_cp")

    def body_measured_cf(self) -> Wrench:
        return self._get("body/measured_cf")

"""A motion-capture system's ROS 2 bridge, emulated: the far end of `drivers.mocap.ros_tracker.RosMocapTracker`.

`FakeRosMocap` publishes every rigid body of the simulated rig as geometry_msgs/PoseStamped
on /<prefix>/<body>/pose (`pose_topic`), as a mocap bridge (vrpn, mocap4r2, natnet_ros2)
does: the frames of a `drivers.mocap.sim.SimTracker` on the world's clock (marker noise, the
rigid-body solve, occlusion and latency), each at its capture time, in frame "world". An
occluded body is not published in that frame (bridges publish nothing for a lost body).
The tracker runs only while some body's topic has a subscriber (`refresh_watched`), as
`rig sim`'s other streams. `unplug()` pulls its cable (a fault for tests): nothing is
published from then on. `rig sim` (`rig.sim_server.ros_node`) calls `publish` every step.
"""

from __future__ import annotations


class FakeRosMocap:
    """The simulated rig's marker bodies on ROS 2 pose topics (see the module docstring).

    world, clock: the simulated world and the clock that steps it; node: the node to publish
    on; prefix: the topics' prefix; noise (m), latency (s), occlusion (probability per body
    and frame), rate (Hz), seed: as `SimTracker`; qos: the publishers' QoS profile.
    """

    def __init__(self, world, clock, node, *, prefix: str, noise: float, latency: float, occlusion: float,
                 rate: float, seed: int, qos) -> None:
        from geometry_msgs.msg import PoseStamped

        from drivers.mocap.ros_tracker import pose_topic
        from rig.sim.world import default_marker_bodies

        self.world, self.clock = world, clock
        self._tracker_args = dict(noise=noise, latency=latency, occlusion=occlusion, rate=rate, seed=seed)
        bodies = [mb.name for n in world.names for mb in default_marker_bodies(n)] + ["world"]
        self.publishers = {b: node.create_publisher(PoseStamped, pose_topic(prefix, b), qos) for b in bodies}
        #: the SimTracker while some body is watched, else None
        self.tracker = None
        self.unplugged = False

    def refresh_watched(self) -> None:
        """Start the tracker when some body's topic has a subscriber, stop it when none has."""
        watched = any(p.get_subscription_count() > 0 for p in self.publishers.values())
        if watched and self.tracker is None:
            from drivers.mocap.sim import SimTracker

            self.tracker = SimTracker(self.world, self.clock, quaternion_order="xyzw", **self._tracker_args)
        elif not watched and self.tracker is not None:
            self.tracker.close()
            self.tracker = None

    def unplug(self) -> None:
        """The tracker's cable pulled: no pose is published from now on."""
        self.unplugged = True

    def publish(self, stamp_ns) -> None:
        """Publish the frames the tracker delivered since the last call; `stamp_ns(t)`: the
        header stamp (ns) of world time t (s)."""
        if self.tracker is None:
            return
        from drivers.common.cdr import write_pose_stamped

        frames = self.tracker.frames()
        if self.unplugged:
            return
        for frame in frames:
            stamp = stamp_ns(frame.t)
            for body, pose in frame.bodies.items():
                if pose is None:
                    continue  # occluded: bridges publish nothing for a lost body
                xyzw = frame.quaternions[body]  # frame.quaternion_order == "xyzw", as on the wire
                self.publishers[body].publish(write_pose_stamped(stamp, "world", pose.position.tolist() + [
                    float(xyzw[0]), float(xyzw[1]), float(xyzw[2]), float(xyzw[3])]))

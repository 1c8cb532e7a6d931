"""The simulated rig served over ROS 2 as whole dVRK PSMs, mocap poses and the operator's channel."""

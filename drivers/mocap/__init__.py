"""Motion capture: the ROS 2 pose tracker (ros_tracker), Motive CSV exports (motive_csv) and the in-process twin (sim.SimTracker); NatNet is drivers/natnet."""

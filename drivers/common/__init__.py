"""What every driver shares: CDR bytes, quaternions, the ROS 2 session and its exit, clock offsets, the time base."""

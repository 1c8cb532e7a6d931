"""The operator as a device: the console and ROS drivers (driver), the simulated operator and the server `rig sim` runs for it (sim)."""

"""The devices of a configuration: the factory procedures call, the rig clock, the load-cell calibrations found in logs/."""

"""The mathematics of fitting: axis and pivot fits, base parameters, LS/WLS/SDP, excitation, friction, effects; never a device."""

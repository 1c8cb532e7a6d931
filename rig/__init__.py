"""dvrk-rig: the kernel (PSM model, simulated world, configuration, runs, CLI).

Units are SI everywhere: m, rad, N, N m, s. Joints are numbered 1-3 in user-facing text
and 0-2 in arrays.
"""

__version__ = "0.1.0"

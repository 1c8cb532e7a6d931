"""The dVRK arm: its CRTK driver over ROS 2 (RosArm), its in-process twin (sim.SimArm) and the emulators of the console's PSM that `rig sim` serves (sim_psm.SimPSM, sim_arm_state.SimArmState)."""

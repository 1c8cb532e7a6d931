"""The dVRK arm: its CRTK driver over ROS 2 (RosArm), its in-process twin (sim.SimArm) and the
emulators of the console's PSM that `rig sim` serves (fake_psm.FakePSM, fake_arm_state.FakeArmState)."""

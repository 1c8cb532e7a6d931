"""The PSM model: kinematics, dynamics, tools, the wrist plant, plant effects and the identified-model file."""

"""The simulated rig's world (PSM plants, the object, marker bodies) and its compiled step."""

"""The 6-DOF arm in the diagnosis: its adapter (tool-point distances), closed-form kinematics,
effect aliases and discovery on joint-angle terms."""

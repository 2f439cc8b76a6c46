"""The robot: its description (joints, limits, neutral pose) and forward kinematics."""

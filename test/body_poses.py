"""Poses for the body tests: the neutral pose with some joints set."""

from __future__ import annotations

import numpy as np

# a speaker's forearm resting on the belly, retargeted: Pepper's forearm in its torso and tablet
INSIDE = {"LShoulderPitch": 1.22, "LShoulderRoll": 0.04, "LElbowRoll": -1.32, "LElbowYaw": -0.19}
AWAY = {"LShoulderPitch": 0.6, "LShoulderRoll": 0.9, "LElbowRoll": -0.6, "LElbowYaw": -1.0}
RIGHT_AWAY = {"RShoulderPitch": 0.6, "RShoulderRoll": -0.9, "RElbowRoll": 0.6, "RElbowYaw": 1.0}


def pose_with(robot, **angles) -> np.ndarray:
    """The robot's neutral pose with the named joints at the given angles (rad)."""
    pose = robot.neutral_rad.copy()
    for name, value in angles.items():
        pose[robot.names.index(name)] = value
    return pose

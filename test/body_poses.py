"""Poses for the body tests: the neutral pose with some joints set."""

from __future__ import annotations

import numpy as np


def pose_with(robot, **angles) -> np.ndarray:
    """The robot's neutral pose with the named joints at the given angles (rad)."""
    pose = robot.neutral_rad.copy()
    for name, value in angles.items():
        pose[robot.names.index(name)] = value
    return pose

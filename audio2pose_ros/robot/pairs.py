"""Which pairs of Pepper's links a body model checks for clearance (ROS-free, no Pinocchio).

Every link of an arm that the arm's joints move (bicep, elbow, forearm, wrist, hand) against
every link of the rest of the body (torso with the tablet and the neck base, neck, head, hip,
pelvis, legs and base) and against every link of the other arm (its shoulder included). Not
checked, like an allowed-collision matrix: links of one arm against each other (adjacent, they
overlap by construction), and the shoulder balls against the body: they turn about their own
centre, fixed to the torso, so their clearance does not depend on any command (the head cannot
reach them within its limits; ``test/test_body.py`` checks both by sampling).

Both body models use this one rule: the exact one of the self-collision guard
(:mod:`audio2pose_ros.robot.body`) and the capsules of body-aware sampling
(:mod:`audio2pose_ros.robot.capsules`), and the one check of the poses they are asked about
(:func:`pose_array`).
"""

from __future__ import annotations

import numpy as np

ARM_LINK_PREFIXES = {
    "left": ("LBicep", "LElbow", "LForeArm", "l_wrist", "l_gripper"),
    "right": ("RBicep", "RElbow", "RForeArm", "r_wrist", "r_gripper"),
}
SHOULDER_LINKS = {"left": "LShoulder", "right": "RShoulder"}


def checked_pair(link_a: str, link_b: str) -> bool:
    """Whether the ordered pair (``link_a``, ``link_b``) is checked, counting each pair once.

    ``link_a`` is the arm's link; arm against arm is counted once, from the left arm.
    """
    for side, links in ARM_LINK_PREFIXES.items():
        if link_a not in links:
            continue
        if link_b in (*links, SHOULDER_LINKS[side]):
            return False  # the arm's own links
        other = "right" if side == "left" else "left"
        if link_b in ARM_LINK_PREFIXES[other]:
            return side == "left"  # arm against arm: once, from the left
        return True  # the body, or the other arm's shoulder
    return False


def pose_array(poses_rad: np.ndarray, n_joints: int) -> np.ndarray:
    """``poses_rad`` as a float array of shape (n_joints,) or (N, n_joints), every angle finite.

    Raises:
        ValueError: another shape, or a NaN or infinite angle.
    """
    poses = np.asarray(poses_rad, dtype=np.float64)
    if poses.shape[-1:] != (n_joints,) or poses.ndim > 2:
        raise ValueError(
            f"poses must be (n_joints,) or (N, n_joints) with n_joints = {n_joints}, "
            f"got shape {poses.shape}"
        )
    if not np.isfinite(poses).all():
        raise ValueError("poses must be finite")
    return poses

"""Retargeted arm poses moved clear of Pepper's body before they become training targets (ours).

People's bodies are not Pepper's: a speaker's forearm resting on their belly or a hand on a hip
is, retargeted joint by joint (:mod:`.upper_body`), a forearm inside Pepper's wider torso and
chest tablet or a hand in its hip. In the lecture the default model learns its arms from, 62 % of
the frames with both arms seen bring an arm link closer than the self-collision guard's 2 cm
margin (:mod:`audio2pose_ros.motion.body_guard`) and 42 % put one inside the body. A model
trained on such targets learns to put its arms there, and the guard then has to hold them.

So every importer (:func:`~.common.assemble_clip`) moves each frame whose observed arm comes
closer than :data:`TRAINING_CLEARANCE_M` to the nearest clear pose it finds
(:meth:`~audio2pose_ros.robot.body.BodyModel.push_out`: only the joints of the offending pair,
up the clearance gradient, within the joint limits). The clearance is the guard's margin and
3 cm more, so that the sampling noise around a learned pose does not bring it back in. Frames
without an observed arm keep the neutral pose they were given (:func:`~.common.finish_angles`).

A push takes a few milliseconds per frame (3 ms for random poses inside the body), and the
targets are 4 Hz low-passed (seed 003 section 4.2.3), so within a run of frames that need it
only every :data:`KEYFRAME_STEP`-th frame and the run's last are pushed and the correction is
interpolated linearly in between. Neighbouring pushes can find different ways out, so the
correction is then low-passed like the targets, and the frames that leaves short of the
clearance are pushed again (by little), up to :data:`SMOOTHING_PASSES` times; the last pass is
not smoothed.
"""

from __future__ import annotations

import numpy as np

from audio2pose_ros.data.runs import true_runs
from audio2pose_ros.motion.smoothing import butterworth_zero_phase
from audio2pose_ros.robot.body import BodyModel
from audio2pose_ros.robot.description import RobotDescription
from audio2pose_ros.timebase import FRAME_RATE_HZ

TRAINING_CLEARANCE_M = 0.05  # the guard's default 2 cm margin and 3 cm for the sampling noise
KEYFRAME_STEP = 5  # 50 ms on the 100 Hz grid
TOLERANCE_M = 0.002  # a smoothed frame this much short of the clearance is kept
SMOOTHING_PASSES = 3


def clear_of_body(
    angles_rad: np.ndarray,
    mask: np.ndarray,
    robot: RobotDescription,
    clearance_m: float = TRAINING_CLEARANCE_M,
) -> tuple[np.ndarray, np.ndarray]:
    """Move the frames whose observed arms are too close to the body (see the module text).

    Args:
        angles_rad: (T, J) finite angles within the limits, in the robot's joint order.
        mask: (T, J) True where observed.
        robot: joint order, groups and limits.
        clearance_m: the clearance the observed arms get (m).

    Returns:
        ``(angles, moved_rad)``: the angles with only observed joints changed, and per frame the
        largest change of a joint (rad; 0 for frames left alone).

    """
    angles = np.array(angles_rad, dtype=np.float64, copy=True)
    moved = np.zeros(len(angles))
    arms = np.asarray(mask)[:, robot.group_mask("arms")].any(axis=1)
    if not arms.any():
        return angles, moved
    body = BodyModel.load(robot)
    body.reset()  # answers depend on this clip's poses alone: an import is reproducible
    clearance = np.full(len(angles), np.inf)
    clearance[arms] = body.clearance(angles[arms])
    short = clearance < clearance_m
    target = angles.copy()
    for start, stop in true_runs(short):
        keys = np.unique(np.append(np.arange(start, stop, KEYFRAME_STEP), stop - 1))
        delta = body.push_out(angles[keys], clearance_m) - angles[keys]
        frames = np.arange(start, stop)
        for j in range(robot.n_joints):
            target[start:stop, j] += np.interp(frames, keys, delta[:, j])
    for _ in range(SMOOTHING_PASSES):
        # neighbouring pushes can choose different ways out: low-pass the correction as the
        # targets are, then push again whatever it leaves short (by little, so by little)
        correction = butterworth_zero_phase(target - angles, rate_hz=FRAME_RATE_HZ)
        target = np.clip(angles + correction, robot.lower_rad, robot.upper_rad)
        left = np.flatnonzero(arms)
        left = left[body.clearance(target[left]) < clearance_m - TOLERANCE_M]
        if not left.size:
            break
        target[left] = body.push_out(target[left], clearance_m)
    out = np.where(mask, target, angles)
    moved = np.abs(out - angles).max(axis=1)
    return out, moved

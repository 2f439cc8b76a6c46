"""Retargeting people's arms to Pepper (synthetic skeletons, known angles) and lecture clips."""

import numpy as np
import pytest

from audio2pose_ros.data.importers.lecture import LECTURE_LICENCE, TEST_SPAN_S, lecture_clips
from audio2pose_ros.data.importers.video import POSE_INDEX, VideoTracks, body_angles
from audio2pose_ros.timebase import complete_frames


def rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


BODY_TO_MEDIAPIPE = np.array([[0, 1, 0], [0, 0, -1], [-1, 0, 0]])  # x: image right, y: down


def arm_points(shoulder, pitch, roll, yaw, elbow_roll, lean=0.0):
    """Elbow and wrist of an arm posed by Pepper's chain (body frame: x fwd, y left, z up)."""
    frame = rot_x(lean) @ rot_y(pitch) @ rot_z(roll)
    elbow = shoulder + 0.3 * frame[:, 0]
    forearm = frame @ rot_x(yaw) @ rot_z(elbow_roll) @ np.array([1.0, 0.0, 0.0])
    return elbow, elbow + 0.25 * forearm


def skeleton(angles, lean):
    """33 MediaPipe world landmarks of a person facing the camera, arms posed by ``angles``."""
    points = np.zeros((33, 3))
    hips = {"left_hip": np.array([0, 0.1, 0.0]), "right_hip": np.array([0, -0.1, 0.0])}
    shoulders = {
        side: rot_x(lean) @ np.array([0, 0.18 * sign, 0.5])
        for side, sign in (("left", 1), ("right", -1))
    }
    body = {**hips, **{f"{s}_shoulder": p for s, p in shoulders.items()}}
    for side, prefix in (("left", "L"), ("right", "R")):
        elbow, wrist = arm_points(
            shoulders[side],
            *(
                angles[prefix + j]
                for j in ("ShoulderPitch", "ShoulderRoll", "ElbowYaw", "ElbowRoll")
            ),
            lean=lean,
        )
        body[f"{side}_elbow"], body[f"{side}_wrist"] = elbow, wrist
    for name, point in body.items():
        points[POSE_INDEX[name]] = BODY_TO_MEDIAPIPE @ point
    return points


POSES = [
    {"ShoulderPitch": 1.2, "ShoulderRoll": 0.3, "ElbowYaw": -0.8, "ElbowRoll": -0.9},
    {"ShoulderPitch": 0.4, "ShoulderRoll": 0.1, "ElbowYaw": 0.5, "ElbowRoll": -1.3},
    {"ShoulderPitch": 1.5, "ShoulderRoll": 0.6, "ElbowYaw": -1.5, "ElbowRoll": -0.4},
]


def tracks_of(frames, visible):
    n = len(frames)
    visibility = np.where(np.asarray(visible)[:, None], 1.0, 0.0) * np.ones((n, 33))
    return VideoTracks(
        np.arange(n) / 15.0,
        np.zeros(n, bool),
        np.tile(np.eye(3), (n, 1, 1)),
        np.full(n, np.inf),
        np.asarray(frames),
        visibility,
    )


def mirrored(pose):
    """The right arm's angles for the same pose mirrored (Pepper's sign conventions)."""
    return {k: (v if k == "ShoulderPitch" else -v) for k, v in pose.items()}


@pytest.mark.parametrize("lean", [0.0, 0.2, -0.15])
@pytest.mark.parametrize("pose", POSES)
def test_when_a_skeleton_is_posed_with_known_angles_expect_them_back(pose, lean, robot):
    angles = {"L" + k: v for k, v in pose.items()} | {"R" + k: v for k, v in mirrored(pose).items()}
    recovered, observed = body_angles(tracks_of([skeleton(angles, lean)], [True]), robot)
    for name, value in angles.items():
        j = robot.names.index(name)
        assert observed[0, j]
        assert recovered[0, j] == pytest.approx(value, abs=1e-6), name
    assert recovered[0, robot.names.index("HipRoll")] == pytest.approx(
        lean, abs=1e-6
    )  # Rx(HipRoll) z = spine


# gesturing 6 cm clear of Pepper's body, so the importers' last step (arms moved out of the body)
# leaves the angles as they are
CLEAR = {"ShoulderPitch": 1.2, "ShoulderRoll": 1.0, "ElbowYaw": -0.8, "ElbowRoll": -0.9}


def test_when_the_arms_disappear_expect_clips_cut_there_and_no_zero_filled_frames(robot):
    fps, seconds = 15.0, 150.0
    n = int(seconds * fps)
    times = np.arange(n) / fps
    visible = ~((times > 20) & (times < 30)) & ~((times > 100) & (times < 112))
    rng = np.random.default_rng(0)
    frames = []
    for t in times:
        pose = {k: v + 0.1 * np.sin(t + i) for i, (k, v) in enumerate(CLEAR.items())}
        angles = {"L" + k: v for k, v in pose.items()}
        angles |= {"R" + k: v for k, v in mirrored(pose).items()}
        frames.append(skeleton(angles, 0.0) + rng.normal(0, 1e-4, (33, 3)))
    audio = np.zeros(int(seconds * 16000), np.float32)
    clips = lecture_clips(tracks_of(frames, visible), audio, robot, "synthetic.webm")
    starts = [float(c.info.clip_id.split("_")[1].removesuffix("s")) for c in clips]
    assert len(clips) == 3
    assert starts[1] == pytest.approx(30.15, abs=0.3)
    assert [c.info.split for c in clips] == [
        "test" if TEST_SPAN_S[0] <= s < TEST_SPAN_S[1] else "train" for s in starts
    ]
    assert "test" in [c.info.split for c in clips]
    head = robot.group_mask("head")
    pitch = robot.names.index("LShoulderPitch")
    for clip in clips:
        assert clip.info.licence == LECTURE_LICENCE
        assert complete_frames(clip.audio.size) == clip.n_frames
        assert not clip.mask[:, head].any()  # the lecture does not label the head
        assert clip.mask[:, ~head].mean() > 0.95
        known = clip.angles_rad[clip.mask[:, pitch], pitch]
        assert np.all(np.abs(known - CLEAR["ShoulderPitch"]) < 0.15)  # no zeros, no neutral


def test_when_the_lecturer_holds_a_hand_up_at_the_board_expect_that_stretch_cut_out(robot):
    """A hand above the shoulder for seconds is writing, not gesturing: no clip holds it."""
    fps, seconds = 15.0, 40.0
    n = int(seconds * fps)
    times = np.arange(n) / fps
    board = (times > 20) & (times < 23)  # 3 s at the board
    brief = (times > 8) & (times < 8.4)  # a 0.4 s gesture above the shoulder: talking
    up = {"ShoulderPitch": -1.0, "ShoulderRoll": 0.3, "ElbowYaw": -0.8, "ElbowRoll": -0.2}
    frames = []
    for raised in board | brief:
        left = up if raised else CLEAR
        angles = {"L" + k: v for k, v in left.items()}
        angles |= {"R" + k: v for k, v in mirrored(CLEAR).items()}
        frames.append(skeleton(angles, 0.0))
    audio = np.zeros(int(seconds * 16000), np.float32)
    clips = lecture_clips(tracks_of(frames, [True] * n), audio, robot, "synthetic.webm")
    spans = [
        (float(c.info.clip_id.split("_")[1].removesuffix("s")), c.n_frames / 100.0) for c in clips
    ]
    assert len(clips) == 2
    assert (
        spans[0][0] + spans[0][1] < 20.0
    )  # the first ends before the board, the brief gesture in it
    assert spans[0][0] < 8.0
    assert spans[1][0] > 23.0  # the second starts after it

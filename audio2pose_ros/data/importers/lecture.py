"""A lecture recording -> arm and hip clips.

The lecture the default model learns from ("Physicsworks" by Walter Lewin, CC BY 3.0; see
doc/credits.md; ``LECTURE_VIDEO`` of ``make default-model``) shows one standing lecturer whose arms
are visible in about 84 of its 203 s, between camera cuts. This module runs the video importer's
trackers (:func:`~audio2pose_ros.data.importers.video.track_video`, MediaPipe Pose world landmarks)
and its retargeting to Pepper's shoulder, elbow and hip joints
(:func:`~audio2pose_ros.data.importers.video.body_angles`, geometry in
:mod:`~audio2pose_ros.data.importers.upper_body`), resamples to the 100 Hz audio grid (seed 003
section 4.2.3) and cuts the recording into clips at the stretches where the arms are seen:

- the head is masked everywhere (the face is small, often turned away or off screen, and the
  talking-head clips label the head);
- a joint is observed only where MediaPipe sees its keypoints and both arms are seen (in
  close-ups with the arms out of frame MediaPipe still reports one arm with high visibility);
  gaps of up to 0.25 s are bridged (:data:`~audio2pose_ros.data.importers.common.MAX_GAP_S`), and
  :data:`EDGE_S` at both ends of every
  observed stretch is masked as well, because the 4 Hz smoothing there mixes in unobserved
  frames: frames without visible arms are masked out of training, never filled with zeros;
- stretches at the board (:func:`board_frames`: a wrist held above the shoulder for a second or
  more, writing or pointing) are masked too: the default model learns how a person gestures
  while talking, not how a lecturer writes on a board;
- every stretch of at least :data:`MIN_STRETCH_S` with visible arms becomes one clip, with its
  audio; the stretch at :data:`TEST_SPAN_S` (the speaker gesturing at the blackboard) is the test
  split, held out of training, the others train.

Attribution (CC BY 3.0) travels with every clip: :data:`LECTURE_LICENCE`.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from audio2pose_ros.data.dataset import Clip, ClipInfo, Dataset
from audio2pose_ros.data.importers.common import HEAD_JOINTS, assemble_clip
from audio2pose_ros.data.importers.media import read_audio
from audio2pose_ros.data.importers.video import VideoTracks, body_angles, track_video
from audio2pose_ros.data.runs import true_runs
from audio2pose_ros.robot.body import BodyModel
from audio2pose_ros.robot.description import RobotDescription
from audio2pose_ros.timebase import SAMPLES_PER_FRAME, WINDOW_SAMPLES, complete_frames

LECTURE_LICENCE = (
    'CC BY 3.0; "Physicsworks" by Walter Lewin (MIT OpenCourseWare 8.01, Lecture 11, "Work, '
    'Energy, and Universal Gravitation"), from Wikimedia Commons (File:Physicsworks.ogv), '
    "licensed under CC BY 3.0. Transcoded to WebM 320x240; changes by this project: upper-body "
    "pose estimated with MediaPipe Pose and retargeted to Pepper's arm and hip joints"
)
LECTURE_SPEAKER = "lewin"
TEST_SPAN_S = (111.0, 137.0)  # front shot at the blackboard, gesturing (SOURCES.md)
MIN_STRETCH_S = 2.0
EDGE_S = 0.15
BOARD_S = 1.0  # a wrist above its shoulder this long: at the board, not gesturing while talking
BOARD_PAD_S = 0.25  # frames this close to such a stretch go with it (reaching up, coming down)


def _erode(mask: np.ndarray, frames: int) -> np.ndarray:
    """Shrink every run of True in each column by ``frames`` at both ends."""
    out = mask.copy()
    for shift in range(1, frames + 1):
        out[shift:] &= mask[:-shift]
        out[:-shift] &= mask[shift:]
    return out


def board_frames(body: BodyModel, angles: np.ndarray, known: np.ndarray) -> np.ndarray:
    """(T,) frames at the board: a wrist above its shoulder for :data:`BOARD_S` or longer.

    Speakers who talk raise a hand above the shoulder now and then, for a moment; a lecturer
    writing or pointing on the board keeps it there. Each run of frames (arms known) with a
    wrist above its shoulder (:meth:`~audio2pose_ros.robot.body.BodyModel.wrist_heights`) of at
    least :data:`BOARD_S` counts, widened by :data:`BOARD_PAD_S` on both sides.
    """
    arms = body.robot.group_mask("arms")
    seen = known[:, arms].all(axis=1)
    up = np.zeros(len(angles), bool)
    rows = np.flatnonzero(seen)
    if rows.size:
        up[rows] = body.wrist_heights(np.nan_to_num(angles[rows])).max(axis=1) > 0.0
    board = np.zeros(len(angles), bool)
    pad = round(BOARD_PAD_S * 100)
    for start, stop in true_runs(up):
        if stop - start >= BOARD_S * 100:
            board[max(0, start - pad) : stop + pad] = True
    return board


def lecture_clips(
    tracks: VideoTracks, audio: np.ndarray, robot: RobotDescription, source: str
) -> list[Clip]:
    """Cut the tracked lecture into clips of visible arms (see the module docstring).

    Args:
        tracks: per-video-frame trackers' output (:func:`track_video` with the body).
        audio: the recording's 16 kHz mono audio.
        robot: joint order, limits and neutral pose.
        source: file name recorded in each clip's index entry.

    Returns:
        Clips ``lecture_<start>s`` in time order, split 'test' inside :data:`TEST_SPAN_S`.

    """
    angles, observed = body_angles(tracks, robot)
    for name in HEAD_JOINTS:
        observed[:, robot.names.index(name)] = False
    info = ClipInfo("lecture", LECTURE_SPEAKER, source, LECTURE_LICENCE)
    whole, _ = assemble_clip(
        tracks.times_s, angles, observed, np.zeros(tracks.times_s.size), audio, info, robot
    )
    mask = _erode(whole.mask, round(EDGE_S * 100))
    mask &= ~board_frames(BodyModel.load(robot), whole.angles_rad, mask)[:, None]
    shoulders = [robot.names.index(f"{side}ShoulderPitch") for side in "LR"]
    both = np.asarray(mask[:, shoulders].all(axis=1))
    mask &= both[:, None]  # one arm alone is mostly a close-up's guess (SOURCES.md)
    arms = both
    clips = []
    for start, stop in true_runs(arms):
        if stop - start < MIN_STRETCH_S * 100:
            continue
        start_s = start / 100.0
        split = "test" if TEST_SPAN_S[0] <= start_s < TEST_SPAN_S[1] else "train"
        piece = audio[start * SAMPLES_PER_FRAME : (stop - 1) * SAMPLES_PER_FRAME + WINDOW_SAMPLES]
        n = min(stop - start, complete_frames(piece.size))
        clip_info = ClipInfo(
            f"lecture_{start_s:06.2f}s", LECTURE_SPEAKER, source, LECTURE_LICENCE, split
        )
        clips.append(
            Clip(clip_info, piece, whole.angles_rad[start : start + n], mask[start : start + n])
        )
    return clips


def import_lecture(
    path: Path,
    dataset_dir: Path,
    robot: RobotDescription,
    progress: Callable[[str], None] = print,
) -> Dataset:
    """Track the lecture video and write its clips as a new data set."""
    progress(f"tracking {path.name} with MediaPipe Pose (about two minutes)")
    audio = read_audio(path)
    tracks = track_video(path, body=True, face=False)  # the head is not labelled here
    dataset = Dataset.create(dataset_dir, robot)
    for clip in lecture_clips(tracks, audio, robot, f"{path.name} (lecture video)"):
        dataset.add(clip, robot)
    progress(f"{len(dataset.clips)} clips with visible arms")
    return dataset

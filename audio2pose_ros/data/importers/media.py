"""Reading media files: audio through ffmpeg (the imageio-ffmpeg wheel's binary), video frames.

Seed 003 section 4.2.2 averages the audio to one channel and resamples it to 16 kHz; ffmpeg does
both here (``-ac 1 -ar 16000``) for any container and codec it reads.
"""

from __future__ import annotations

import subprocess
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from audio2pose_ros.data.importers.common import ImporterError
from audio2pose_ros.timebase import SAMPLE_RATE_HZ


def ffmpeg_executable() -> str:
    """Path of the ffmpeg binary shipped in the imageio-ffmpeg wheel."""
    import imageio_ffmpeg

    return imageio_ffmpeg.get_ffmpeg_exe()


def read_audio(path: Path) -> np.ndarray:
    """The audio track of any file ffmpeg reads, as 16 kHz mono float32 in [-1, 1].

    Raises:
        ImporterError: the file is missing, unreadable, or has no (or an empty) audio track.

    """
    if not path.is_file():
        raise ImporterError(f"{path}: no such file")
    command = [
        ffmpeg_executable(), "-nostdin", "-v", "error", "-i", str(path), "-map", "0:a:0",
        "-vn", "-ac", "1", "-ar", str(SAMPLE_RATE_HZ), "-f", "f32le", "-acodec", "pcm_f32le",
        "pipe:1",
    ]  # fmt: skip
    result = subprocess.run(command, capture_output=True, check=False)
    if result.returncode != 0:
        message = result.stderr.decode(errors="replace").strip().splitlines()
        if any("matches no streams" in line for line in message):
            raise ImporterError(f"{path}: no audio track")
        reason = message[-1] if message else f"ffmpeg exit code {result.returncode}"
        raise ImporterError(f"{path}: cannot read the audio ({reason})")
    audio = np.frombuffer(result.stdout, dtype="<f4")
    if audio.size == 0:
        raise ImporterError(f"{path}: the audio track is empty")
    return np.clip(audio, -1.0, 1.0).astype(np.float32)


def video_frames(path: Path) -> Iterator[tuple[float, np.ndarray]]:
    """Decode a video: ``(time_s, rgb)`` per frame, rgb (H, W, 3) uint8.

    Times are the frames' presentation times from OpenCV when they increase, else
    ``index / fps`` (constant frame rate). Audio and video are assumed to start together.

    Raises:
        ImporterError: the file does not open as a video or holds no frames.

    """
    import cv2

    capture = cv2.VideoCapture(str(path))
    if not capture.isOpened():
        raise ImporterError(f"{path}: not a readable video")
    fps = capture.get(cv2.CAP_PROP_FPS) or 25.0
    previous_s, index = -np.inf, 0
    try:
        while True:
            ok, bgr = capture.read()
            if not ok:
                break
            time_s = capture.get(cv2.CAP_PROP_POS_MSEC) / 1000.0
            if not time_s > previous_s:
                time_s = index / fps
            previous_s = time_s
            index += 1
            yield time_s, cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    finally:
        capture.release()
    if index == 0:
        raise ImporterError(f"{path}: no video frames")

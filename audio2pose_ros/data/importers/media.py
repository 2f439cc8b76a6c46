"""Reading media files through ffmpeg (the imageio-ffmpeg wheel's binary), streamed and bounded.

Seed 003 section 4.2.2 averages the audio to one channel and resamples it to 16 kHz; ffmpeg does
both here (``-ac 1 -ar 16000``) for any container and codec it reads.

A media file is untrusted input, and a few megabytes can hold hours of audio or frames of
gigapixels. What is read is bounded before it is decoded:

- :func:`probe_media` reads the streams' headers (no decoding): whether there is audio, the
  first video stream's frame size and rate;
- :func:`read_audio` reads at most ``max_seconds`` (ffmpeg stops reading the file there), or
  refuses a track longer than :data:`MAX_AUDIO_S`, streaming ffmpeg's output into one array;
- :func:`video_frames` refuses frames over :data:`MAX_SOURCE_PIXELS` before decoding any, and
  has ffmpeg hand over one frame at a time, scaled down to fit :data:`MAX_FRAME_SIDE_PX` (what
  MediaPipe needs: its models look at 128 to 256 pixel crops) at no more than
  :data:`MAX_FRAME_RATE_HZ`;
- every ffmpeg run refuses any single allocation over :data:`MAX_ALLOC_BYTES` (``-max_alloc``),
  which stops a stream whose frames grow past its header's size.
"""

from __future__ import annotations

import io
import re
import subprocess
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np

from audio2pose_ros.data.importers.common import ImporterError
from audio2pose_ros.timebase import SAMPLE_RATE_HZ

MAX_AUDIO_S = 3600.0  # a longer audio track is refused (a data set's longest clip)
MAX_SOURCE_PIXELS = 7680 * 4320  # 8K UHD: larger frames are refused before decoding
MAX_FRAME_SIDE_PX = 1280  # frames are scaled down to fit this square before they are handed over
MAX_FRAME_RATE_HZ = 30.0  # frames beyond this rate are dropped (ffmpeg's fps filter)
MAX_ALLOC_BYTES = 128 * 2**20  # ffmpeg's largest single allocation (an 8K RGB frame is 100 MB)
_ERROR_TAIL_BYTES = 4096  # of ffmpeg's error output, the end is kept for the message
_READ_BYTES = 1 << 20  # ffmpeg's audio output is read this much at a time


def ffmpeg_executable() -> str:
    """Path of the ffmpeg binary shipped in the imageio-ffmpeg wheel."""
    import imageio_ffmpeg

    return imageio_ffmpeg.get_ffmpeg_exe()


def _ffmpeg() -> list[str]:
    """The ffmpeg command's start shared by every run here: no input, allocations bounded."""
    return [
        ffmpeg_executable(), "-nostdin", "-hide_banner", "-max_alloc", str(MAX_ALLOC_BYTES),
    ]  # fmt: skip


@dataclass(frozen=True)
class MediaInfo:
    """What a media file's headers declare (:func:`probe_media`); nothing is decoded.

    Attributes:
        has_audio: the file has an audio stream.
        frame_size: (width, height) in pixels of the first video stream as shown (after its
            rotation), or None without a video stream.
        frame_rate_hz: that stream's frame rate, None when it declares none.
        duration_s: the container's duration, None when it declares none (a recording of a
            browser's MediaRecorder); a header's claim, not a measure.
    """

    has_audio: bool
    frame_size: tuple[int, int] | None
    frame_rate_hz: float | None
    duration_s: float | None


_STREAM = re.compile(r"^\s*Stream #0:\d+.*?: (Video|Audio): (.*)$")
_SIZE = re.compile(r"(?:^|[ ,])(\d{1,6})x(\d{1,6})(?:[ ,\[]|$)")
_RATE = re.compile(r"(\d+(?:\.\d+)?)(k?) (?:fps|tbr)")
_ROTATION = re.compile(r"rotation of (-?\d+(?:\.\d+)?) degrees")
_DURATION = re.compile(r"^\s*Duration: (\d+):(\d\d):(\d\d(?:\.\d+)?)")


def probe_media(path: Path) -> MediaInfo:
    """Read a media file's stream headers (ffmpeg's description of its input; no decoding).

    Raises:
        ImporterError: the file is missing, or ffmpeg does not read it as media.
    """
    if not path.is_file():
        raise ImporterError(f"{path}: no such file")
    result = subprocess.run(
        [*_ffmpeg(), "-i", str(path)], capture_output=True, check=False, timeout=60
    )  # without an output ffmpeg describes the input, then exits 1
    lines = result.stderr.decode(errors="replace").splitlines()
    if not any(line.startswith("Input #0") for line in lines):
        reason = lines[-1].strip() if lines else f"ffmpeg exit code {result.returncode}"
        raise ImporterError(f"{path}: not a readable media file ({reason})")
    has_audio, size, rate, duration = False, None, None, None
    video_at = -1
    for at, line in enumerate(lines):
        stream = _STREAM.match(line)
        if stream and stream[1] == "Audio":
            has_audio = True
        elif stream and video_at < 0:
            video_at = at
            found = _SIZE.search(stream[2])
            size = (int(found[1]), int(found[2])) if found else (0, 0)
            rates = _RATE.findall(stream[2])
            if rates:
                rate = float(rates[0][0]) * (1000.0 if rates[0][1] else 1.0)
        elif stream is None and (moment := _DURATION.match(line)):
            hours, minutes, seconds = moment.groups()
            duration = 3600.0 * int(hours) + 60.0 * int(minutes) + float(seconds)
    if video_at >= 0 and size is not None:
        # a rotated stream (a phone's portrait video) is shown, and decoded, turned
        for line in lines[video_at + 1 :]:
            if _STREAM.match(line):
                break
            turn = _ROTATION.search(line)
            if turn and round(abs(float(turn[1]))) % 180 == 90:
                size = (size[1], size[0])
    return MediaInfo(has_audio, size, rate, duration)


def _error_tail(stream: IO[bytes]) -> list[str]:
    """The last lines of ffmpeg's error output, written to a temporary file."""
    stream.seek(0, 2)
    stream.seek(max(0, stream.tell() - _ERROR_TAIL_BYTES))
    return stream.read().decode(errors="replace").strip().splitlines()


def read_audio(path: Path, max_seconds: float | None = None) -> np.ndarray:
    """The audio track of any file ffmpeg reads, as 16 kHz mono float32 in [-1, 1].

    Args:
        path: the media file.
        max_seconds: read at most this much from the start (ffmpeg stops reading the file
            there); None: the whole track, which must be at most :data:`MAX_AUDIO_S` long.

    Raises:
        ImporterError: the file is missing, unreadable, has no (or an empty) audio track, or
            (without ``max_seconds``) a track longer than :data:`MAX_AUDIO_S`.

    """
    if not path.is_file():
        raise ImporterError(f"{path}: no such file")
    # without a bound of the caller's, a second past the longest track allowed tells it apart
    limit_s = MAX_AUDIO_S + 1.0 if max_seconds is None else max_seconds
    duration = ["-t", f"{limit_s:.3f}"]  # an input option: nothing after it is read
    command = [
        *_ffmpeg(), "-v", "error", *duration, "-i", str(path), "-map", "0:a:0", "-vn", "-sn",
        "-dn", "-ac", "1", "-ar", str(SAMPLE_RATE_HZ), "-f", "f32le", "-acodec", "pcm_f32le",
        "pipe:1",
    ]  # fmt: skip
    capacity = round(limit_s * SAMPLE_RATE_HZ)  # resampling may give a sample more: dropped
    audio = np.empty(capacity, dtype=np.float32)  # pages are taken as they are written
    with tempfile.TemporaryFile() as errors:
        process = subprocess.Popen(
            command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=errors
        )
        output = process.stdout
        assert isinstance(output, io.BufferedReader)
        filled, view = 0, audio.data.cast("B")
        try:
            while filled < view.nbytes:
                n = output.readinto(view[filled : filled + _READ_BYTES])
                if not n:
                    break
                filled += n
        finally:
            view.release()
            output.close()
            if process.poll() is None and filled >= audio.nbytes:
                process.kill()  # all that is wanted was read
            code = process.wait()
        message = _error_tail(errors)
    if filled < audio.nbytes and code != 0:
        if any("matches no streams" in line for line in message):
            raise ImporterError(f"{path}: no audio track")
        reason = message[-1] if message else f"ffmpeg exit code {code}"
        raise ImporterError(f"{path}: cannot read the audio ({reason})")
    n = filled // 4
    if max_seconds is None and n > MAX_AUDIO_S * SAMPLE_RATE_HZ:
        raise ImporterError(f"{path}: the audio is longer than {MAX_AUDIO_S:g} s")
    if n == 0:
        raise ImporterError(f"{path}: the audio track is empty")
    audio.resize(n, refcheck=False)  # shrinks in place: nothing else refers to it
    return np.clip(audio, -1.0, 1.0, out=audio)


def frame_rate(info: MediaInfo) -> float:
    """The rate at which :func:`video_frames` hands frames over: the stream's, at most 30 Hz."""
    rate = info.frame_rate_hz
    return MAX_FRAME_RATE_HZ if rate is None or not 0.0 < rate < MAX_FRAME_RATE_HZ else rate


def check_video(path: Path, info: MediaInfo) -> tuple[int, int]:
    """The first video stream's frame size, after refusing what cannot be read bounded.

    Raises:
        ImporterError: no video stream, a frame size the header does not say, or frames of
            more than :data:`MAX_SOURCE_PIXELS`.
    """
    if info.frame_size is None:
        raise ImporterError(f"{path}: no video stream")
    width, height = info.frame_size
    if width <= 0 or height <= 0:
        raise ImporterError(f"{path}: the video does not say its frame size; it is not read")
    if width * height > MAX_SOURCE_PIXELS:
        raise ImporterError(
            f"{path}: video frames of {width}x{height} pixels; frames of at most "
            f"{MAX_SOURCE_PIXELS / 1e6:.0f} megapixels (7680x4320) are read"
        )
    return width, height


def video_frames(
    path: Path, max_seconds: float | None = None
) -> Iterator[tuple[float, np.ndarray]]:
    """Decode a video one frame at a time: ``(time_s, rgb)``, rgb (H, W, 3) uint8.

    Frames come at a constant rate, the stream's own up to :data:`MAX_FRAME_RATE_HZ` (ffmpeg's
    fps filter repeats or drops frames of a variable-rate stream), scaled down (never up) to
    fit :data:`MAX_FRAME_SIDE_PX` with their aspect ratio kept; frame ``k`` is at ``k / rate``
    seconds. Audio and video are assumed to start together.

    Args:
        path: the video file.
        max_seconds: decode at most this much from the start (None: all of it).

    Raises:
        ImporterError: what :func:`check_video` refuses (before anything is decoded), a file
            that does not decode, or no frames.

    """
    info = probe_media(path)
    check_video(path, info)
    rate = frame_rate(info)
    side = MAX_FRAME_SIDE_PX
    fit = (
        f"fps={rate:.6g},"
        f"scale=w='min(iw,{side})':h='min(ih,{side})':force_original_aspect_ratio=decrease"
        ":flags=area"
    )
    duration = [] if max_seconds is None else ["-t", f"{max_seconds:.3f}"]
    command = [
        *_ffmpeg(), "-v", "error", "-threads", "2", *duration, "-i", str(path), "-map", "0:v:0",
        "-an", "-sn", "-dn", "-vf", fit, "-pix_fmt", "rgb24", "-f", "image2pipe", "-c:v", "ppm",
        "pipe:1",
    ]  # fmt: skip
    index = 0
    with tempfile.TemporaryFile() as errors:
        process = subprocess.Popen(
            command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=errors
        )
        output = process.stdout
        assert isinstance(output, io.BufferedReader)
        try:
            while (frame := _ppm_frame(output, path)) is not None:
                yield index / rate, frame
                index += 1
        finally:
            output.close()
            if process.poll() is None:
                process.kill()  # the caller stopped early
            code = process.wait()
        message = _error_tail(errors)
    if index == 0:
        reason = message[-1] if message else f"ffmpeg exit code {code}"
        raise ImporterError(f"{path}: no video frames ({reason})")


def _ppm_frame(stream: io.BufferedReader, path: Path) -> np.ndarray | None:
    """The next frame of ffmpeg's PPM stream (``P6 W H 255``, then the pixels), None at its end."""
    header = [stream.readline(16) for _ in range(3)]
    if not header[0]:
        return None
    size = header[1].split()
    if header[0] != b"P6\n" or header[2] != b"255\n" or len(size) != 2:
        raise ImporterError(f"{path}: the decoder's frames are not readable")
    width, height = int(size[0]), int(size[1])
    if not (0 < width <= MAX_FRAME_SIDE_PX and 0 < height <= MAX_FRAME_SIDE_PX):
        raise ImporterError(f"{path}: a decoded frame of {width}x{height} pixels")
    frame = np.empty((height, width, 3), dtype=np.uint8)
    view = frame.data.cast("B")
    filled = 0
    while filled < view.nbytes:
        n = stream.readinto(view[filled:])
        if not n:
            return None  # ffmpeg stopped inside a frame (its error says why)
        filled += n
    view.release()
    return frame

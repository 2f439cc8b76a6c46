"""Enrollment's memory bound: hostile recordings, small on disk, enrolled in a child process.

Each input is built here in a second or so: four hours of silent FLAC (about 100 KB), a video
of three flat 16000x16000 JPEG frames (3 MB, written byte by byte: a flat JPEG's entropy-coded
data is all zero bytes with one-code Huffman tables), four hours of a tiny video with four hours
of audio, and a data set of ten one-hour clips (copies of one file of 240 KB). ``audio2pose enroll``
runs on each in a child process whose peak memory is measured: the largest resident set of any
one process of its tree (``getrusage(RUSAGE_CHILDREN)``) and, sampled from ``/proc``, the sum of
the peaks of the processes alive together (the child and its ffmpeg). A tree that passes
:data:`KILL_BYTES` is killed and fails the test at once. The verdict is the bound of any input,
:data:`MAX_PEAK_BYTES`; the figures are printed (``-s``).

Then, in this process, each bounded read (audio, frames, a data set's clips), and the console's
side: an upload checked before it is accepted, and the learning child's own memory bound.
"""

from __future__ import annotations

import asyncio
import json
import os
import re
import shutil
import signal
import struct
import subprocess
import sys
import threading
from collections.abc import AsyncIterator
from pathlib import Path

import numpy as np
import pytest

from audio2pose_ros.console.enrollment import EnrollmentError, Enrollments
from audio2pose_ros.data.dataset import Clip, ClipInfo, Dataset
from audio2pose_ros.data.importers import media
from audio2pose_ros.data.importers.common import ImporterError
from audio2pose_ros.robot.description import RobotDescription
from audio2pose_ros.style.personal import recording_clips
from audio2pose_ros.timebase import SAMPLES_PER_FRAME, WINDOW_SAMPLES, complete_frames

MAX_PEAK_BYTES = 1536 * 2**20  # 1.5 GiB: enrollment's bound for any input
KILL_BYTES = 3 * 2**30  # a tree past this is killed (the probe's bound, before the fix)
SAMPLE_PERIOD_S = 0.02  # /proc is read this often


def _process_tree(root: int) -> list[int]:
    """``root`` and its live descendants, from /proc (parents read from each ``stat``)."""
    parents: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat", "rb") as file:
                fields = file.read().rsplit(b")", 1)[1].split()
        except OSError:
            continue
        parents.setdefault(int(fields[1]), []).append(int(entry))
    tree, todo = [], [root]
    while todo:
        pid = todo.pop()
        tree.append(pid)
        todo += parents.get(pid, [])
    return tree


def _high_water_bytes(pid: int) -> int:
    """The peak resident set of one process so far (``VmHWM``), 0 once it is gone."""
    try:
        with open(f"/proc/{pid}/status", encoding="ascii") as file:
            for line in file:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


# runs the command, waits, and prints the largest resident set of any one of its descendants
_LAUNCHER = (
    "import resource, subprocess, sys; code = subprocess.call(sys.argv[1:]); "
    "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024); sys.exit(code)"
)


def run_measured(command: list[str]) -> tuple[int, str, int]:
    """Run ``command`` in a new process group; measure its memory and kill it past KILL_BYTES.

    Returns:
        Its exit code (negative: killed by that signal), its output (stdout and stderr), and
        its peak memory in bytes: the larger of the largest resident set of one process of
        its tree (getrusage of the children, every grandchild included) and the largest sum,
        sampled, of the peaks of the processes alive together.
    """
    launcher = subprocess.Popen(
        [sys.executable, "-c", _LAUNCHER, *command],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,  # its own group: a kill reaches every process of the tree
    )
    tree_peak = [0]
    done = threading.Event()

    def sample() -> None:
        while not done.wait(SAMPLE_PERIOD_S):
            total = sum(_high_water_bytes(pid) for pid in _process_tree(launcher.pid))
            tree_peak[0] = max(tree_peak[0], total)
            if total > KILL_BYTES:
                os.killpg(launcher.pid, signal.SIGKILL)
                return

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    output, _ = launcher.communicate()
    done.set()
    sampler.join()
    lines = output.rstrip().splitlines()
    one_process = int(lines.pop()) if lines and lines[-1].isdigit() else 0
    code = launcher.returncode if launcher.returncode >= 0 or one_process else -signal.SIGKILL
    return code, "\n".join(lines), max(tree_peak[0], one_process)


# --- hostile inputs --------------------------------------------------------------------------


def _ffmpeg(*args: str) -> None:
    subprocess.run(
        [media.ffmpeg_executable(), "-nostdin", "-v", "error", "-y", *args],
        check=True,
        capture_output=True,
    )


def _segment(marker: int, payload: bytes) -> bytes:
    return b"\xff" + bytes([marker]) + struct.pack(">H", len(payload) + 2) + payload


def flat_jpeg(width: int, height: int) -> bytes:
    """A baseline greyscale JPEG of mid-grey pixels (``width * height`` a multiple of 256).

    Both Huffman tables hold one code, '0': DC difference 0, then end of block. Every 8x8 block
    is two zero bits, so the entropy-coded data is ``width * height / 256`` zero bytes.
    """
    one_code = bytes([1] + [0] * 15) + b"\x00"
    return (
        b"\xff\xd8"
        + _segment(0xDB, b"\x00" + b"\x01" * 64)
        + _segment(0xC0, struct.pack(">BHHB", 8, height, width, 1) + b"\x01\x11\x00")
        + _segment(0xC4, b"\x00" + one_code)
        + _segment(0xC4, b"\x10" + one_code)
        + _segment(0xDA, b"\x01\x01\x00\x00\x3f\x00")
        + b"\x00" * (width * height // 256)
        + b"\xff\xd9"
    )


def flat_video(path: Path, width: int, height: int, frames: int, rate_hz: float) -> Path:
    """``frames`` flat JPEG frames at ``rate_hz`` with as long a silence (copied, not encoded)."""
    stream = path.with_suffix(".mjpeg")
    stream.write_bytes(flat_jpeg(width, height) * frames)
    _ffmpeg(
        "-f", "lavfi", "-i", "anullsrc=r=8000:cl=mono", "-f", "mjpeg", "-framerate",
        f"{rate_hz:g}", "-i", str(stream), "-t", f"{frames / rate_hz:g}", "-c:v", "copy",
        "-c:a", "flac", str(path),
    )  # fmt: skip
    stream.unlink()
    return path


def huge_frames_video(path: Path) -> Path:
    """Three flat frames of 16000x16000 pixels at 1 fps, with silent audio (3 MB)."""
    return flat_video(path, 16000, 16000, 3, 1.0)


LONG_S = 4 * 3600  # four hours


def long_audio(path: Path) -> Path:
    """Four hours of silence, about 100 KB of FLAC (8 kHz, 16384-sample frames)."""
    _ffmpeg(
        "-f", "lavfi", "-i", "anullsrc=r=8000:cl=mono:nb_samples=16384", "-t", str(LONG_S),
        "-c:a", "flac", "-frame_size", "16384", str(path),
    )  # fmt: skip
    return path


def long_video(path: Path) -> Path:
    """Four hours of a flat 32x32 picture at one frame in 5 s, with four hours of silence."""
    _ffmpeg(
        "-f", "lavfi", "-i", "anullsrc=r=8000:cl=mono:nb_samples=16384",
        "-f", "lavfi", "-i", "color=c=gray:s=32x32:r=0.2", "-t", str(LONG_S),
        "-c:a", "flac", "-frame_size", "16384", "-c:v", "mjpeg", str(path),
    )  # fmt: skip
    return path


def long_dataset(root: Path, robot: RobotDescription, clips: int = 10, hours: float = 1.0) -> Path:
    """A data set of ``clips`` silent clips of ``hours`` each, no joint observed (small on disk).

    One clip is written and its file copied (the index, JSON, lists the copies).
    """
    samples = int(hours * 3600 * 16000)
    frames = complete_frames(samples)
    dataset = Dataset.create(root, robot)
    audio = np.zeros(samples, dtype=np.float32)
    angles = np.zeros((frames, len(dataset.joint_names)))
    mask = np.zeros(angles.shape, dtype=bool)
    first = ClipInfo("hour_0", "nobody", "silence", "test data")
    dataset.add(Clip(first, audio, angles, mask), robot)
    del audio, angles, mask
    index_file = root / "index.json"
    index = json.loads(index_file.read_text(encoding="utf-8"))
    for k in range(1, clips):  # copies of the first clip's file, listed in the index
        entry = dict(index["clips"][0], clip_id=f"hour_{k}")
        shutil.copyfile(root / "clips" / "hour_0.npz", root / "clips" / f"hour_{k}.npz")
        index["clips"].append(entry)
    index_file.write_text(json.dumps(index), encoding="utf-8")
    return root


def enroll_command(source: Path, out: Path) -> list[str]:
    return [sys.executable, "-m", "audio2pose_ros.cli.main", "enroll", str(source), "-o", str(out)]


# --- the bound, measured -------------------------------------------------------------------

HOSTILE = {  # builder, and what the refusal says
    "four_hours_of_audio": (long_audio, "long_audio.flac", r"no video stream"),
    "three_16000x16000_frames": (
        huge_frames_video,
        "huge.mkv",
        r"video frames of 16000x16000 pixels; frames of at most 33 megapixels",
    ),
    # one frame in 5 s: 12 frames are the first 60 s, all that is decoded
    "four_hours_of_video": (
        long_video,
        "long_video.mkv",
        r"a face was found in only 0 of 12 frames",
    ),
    "ten_hours_data_set": (
        None,
        "ten_hours",
        r"no part \(head, arms, hip\) was observed for 5 s or more in the 60\.0 s used",
    ),
}


@pytest.mark.slow
@pytest.mark.parametrize("kind", list(HOSTILE))
def test_when_enrolling_a_hostile_recording_expect_a_clear_refusal_within_the_memory_bound(
    tmp_path, robot, kind
):
    build, name, refusal = HOSTILE[kind]
    source = long_dataset(tmp_path / name, robot) if build is None else build(tmp_path / name)
    code, output, peak = run_measured(enroll_command(source, tmp_path / "me"))
    print(f"enroll on {kind}: peak {peak / 2**20:.0f} MiB, exit code {code}")
    assert code == 1, output[-2000:]  # refused, not killed at KILL_BYTES
    assert re.search(refusal, output), output[-2000:]
    assert peak <= MAX_PEAK_BYTES


# --- reading bounded, in the process --------------------------------------------------------


def test_when_audio_is_read_with_a_bound_expect_exactly_that_much_of_four_hours(tmp_path):
    audio = media.read_audio(long_audio(tmp_path / "long.flac"), max_seconds=60.0)
    assert audio.shape == (60 * 16000,)
    assert audio.dtype == np.float32


def test_when_audio_without_a_bound_is_longer_than_allowed_expect_a_refusal(tmp_path, monkeypatch):
    monkeypatch.setattr(media, "MAX_AUDIO_S", 10.0)
    path = tmp_path / "twenty_s.flac"
    _ffmpeg("-f", "lavfi", "-i", "anullsrc=r=8000:cl=mono", "-t", "20", str(path))
    with pytest.raises(ImporterError, match=r"twenty_s\.flac: the audio is longer than 10 s"):
        media.read_audio(path)
    assert media.read_audio(path, max_seconds=5.0).size == 5 * 16000


def test_when_frames_are_large_and_fast_expect_them_scaled_and_thinned_before_handed_over(
    tmp_path,
):
    """2048x1024 at 60 fps: frames of 1280x640 (aspect kept) at 30 Hz, one at a time."""
    video = flat_video(tmp_path / "big.mkv", 2048, 1024, 60, 60.0)
    frames = list(media.video_frames(video))
    assert [frame.shape for _, frame in frames] == [(640, 1280, 3)] * 30
    assert [t for t, _ in frames] == [k / 30.0 for k in range(30)]
    assert all((frame == 128).all() for _, frame in frames)  # the flat mid-grey, scaled


def test_when_frames_exceed_8k_expect_a_refusal_from_the_header_before_decoding(tmp_path):
    video = huge_frames_video(tmp_path / "huge.mkv")
    info = media.probe_media(video)
    assert (info.frame_size, info.frame_rate_hz, info.has_audio) == ((16000, 16000), 1.0, True)
    with pytest.raises(ImporterError, match=r"huge\.mkv: video frames of 16000x16000 pixels"):
        media.check_video(video, info)
    with pytest.raises(ImporterError, match=r"16000x16000"):
        next(media.video_frames(video))


def test_when_a_data_set_holds_more_than_the_bound_expect_only_its_first_clips_read(
    tmp_path, robot, speech
):
    """Three clips of 40 s: the first 60 s are the first clip and 20 s of the second; the third
    (an unreadable file here) is never opened, and the cut clip keeps only its own audio."""
    dataset = Dataset.create(tmp_path / "data", robot)
    audio = np.resize(speech, 40 * 16000)
    frames = complete_frames(audio.size)
    for k in range(3):
        angles = np.tile(robot.neutral_rad, (frames, 1))
        mask = np.ones(angles.shape, dtype=bool)
        dataset.add(
            Clip(ClipInfo(f"clip_{k}", "someone", "test", "test"), audio, angles, mask), robot
        )
    (tmp_path / "data" / "clips" / "clip_2.npz").write_bytes(b"not a clip")
    lines: list[str] = []
    clips = recording_clips(tmp_path / "data", robot, lines.append, max_seconds=60.0)
    assert [c.info.clip_id for c in clips] == ["clip_0", "clip_1"]
    assert [c.n_frames for c in clips] == [frames, 6000 - frames]
    assert clips[1].audio.size == SAMPLES_PER_FRAME * (6000 - frames - 1) + WINDOW_SAMPLES
    assert clips[1].angles_rad.base is None  # a copy: the rest of the clip is freed
    assert lines == [f"reading the first 60 s of data set {tmp_path / 'data'}"]


def test_when_a_clip_is_read_in_part_expect_its_first_frames_and_their_audio_only(
    tmp_path, robot, speech
):
    dataset = Dataset.create(tmp_path / "data", robot)
    frames = complete_frames(speech.size)
    angles = np.tile(robot.neutral_rad, (frames, 1)) + np.linspace(0.0, 0.1, frames)[:, None]
    mask = np.broadcast_to(np.arange(frames)[:, None] % 3 != 0, angles.shape).copy()
    dataset.add(Clip(ClipInfo("talk", "someone", "test", "test"), speech, angles, mask), robot)
    whole, part = dataset.load("talk"), dataset.load("talk", max_frames=250)
    assert part.n_frames == 250
    assert part.audio.size == SAMPLES_PER_FRAME * 249 + WINDOW_SAMPLES
    np.testing.assert_array_equal(part.audio, whole.audio[: part.audio.size])
    np.testing.assert_array_equal(part.angles_rad, whole.angles_rad[:250])
    np.testing.assert_array_equal(part.mask, whole.mask[:250])
    assert dataset.load("talk", max_frames=10 * frames).n_frames == frames  # no more than it has


# --- the console ------------------------------------------------------------------------------


async def _chunks(data: bytes) -> AsyncIterator[bytes]:
    for start in range(0, len(data), 1 << 16):
        yield data[start : start + (1 << 16)]


@pytest.mark.parametrize(
    ("build", "name", "refusal"),
    [
        (
            long_video,
            "long_video.mkv",
            r"^the recording is longer than 65 s; learning a style takes a recording of at most "
            r"60 s$",
        ),
        (
            huge_frames_video,
            "huge.mkv",
            r"^the recording cannot be learned from: video frames of 16000x16000 pixels",
        ),
        (long_audio, "long_audio.flac", r"^the recording cannot be learned from: no video stream$"),
    ],
    ids=["four_hours", "16000x16000_frames", "audio_only"],
)
def test_when_an_upload_holds_what_learning_cannot_bound_expect_it_refused_before_learning(
    tmp_path, build, name, refusal
):
    """Refused when it arrives (the page gets 400 and the reason), before any learning child."""
    data = build(tmp_path / name).read_bytes()
    learns = [sys.executable, "-c", "raise SystemExit('the learning child was started')"]
    jobs = Enrollments(tmp_path / "work", learns)
    key = jobs.ticket(1, "Ann", keep=False)
    with pytest.raises(EnrollmentError, match=refusal):
        asyncio.run(jobs.receive(key, "video/x-matroska", _chunks(data)))
    assert not [p for p in (tmp_path / "work").rglob("*") if p.is_file()]
    assert jobs.status()["state"] == "idle"
    assert not jobs.busy


def test_when_the_learning_child_passes_its_memory_bound_expect_that_reason(tmp_path):
    """The real worker and its bound; its learning (a stand-in here) asks for 2 GiB of data.

    The reads of enrollment are bounded on their own (above), so no recording reaches the
    bound: the stand-in's allocation (reserved, never touched) is what passes it.
    """
    wants_two_gib = (
        "import sys, numpy; from audio2pose_ros.console import enroll_worker; "
        "from audio2pose_ros.style import personal; "
        "personal.enroll = lambda *args, **kwargs: numpy.empty(2 * 2**30, dtype=numpy.uint8); "
        "sys.exit(enroll_worker.main())"
    )
    done = subprocess.run(
        [sys.executable, "-c", wants_two_gib, str(tmp_path / "rec.webm"), str(tmp_path / "style")],
        capture_output=True,
        text=True,
        check=False,
    )
    last = (done.stdout.strip().splitlines() or [""])[-1]
    assert (done.returncode, last) == (
        1,
        "ENROLL_FAILED learning needs more memory than its bound of 1.5 GiB",
    ), done.stderr[-2000:]

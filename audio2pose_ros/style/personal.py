"""Personal models: a person's style learned from a recording (``audio2pose enroll``), and using it.

A personal model is a folder::

    me/
      style.yaml       the person's figures per observed part (audio2pose_ros.style.figures)
      ENROLLMENT.md    what was measured, from what, and the settings against the default model

It runs the packaged model (or ``model.safetensors`` in the folder, when present) with the
person's style: every ``--model`` option takes such a folder (:func:`model_and_style`), and the
style resolves into the motion filter's style parameters against the model's own figures
(:func:`style_settings`).

Why a style fit and not a fine-tune (seed 003's subject-dependent models) or a CVAE latent
(seed 002): the styles of our sources differ most in size and tempo (4 to 5 times in head size
between readers and addressers), which speech does not predict, and 60 s of one person holds too
little to retrain the model's speech-to-motion mapping; a fit of per-part size, tempo, arm rest
and height takes seconds, cannot make the motion less safe (the limiter and body guard stay
last) and leaves the model's timing on the speech as it is. The held-out evaluation
(``audio2pose evaluate-style``, model card) measures how well it does.

:func:`enroll` is the library entry the console calls; ``audio2pose enroll`` its command line.
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from audio2pose_ros.data.dataset import Clip, ClipInfo, Dataset
from audio2pose_ros.errors import InputError
from audio2pose_ros.motion.style import StyleSettings
from audio2pose_ros.resources import bundled_speech_paths, default_checkpoint_path
from audio2pose_ros.robot.description import RobotDescription
from audio2pose_ros.style.figures import (
    MIN_PART_S,
    Motion,
    PartFigures,
    StyleError,
    StyleFile,
    load_style,
    measure,
    preset_names,
    resolve,
)
from audio2pose_ros.timebase import FRAME_RATE_HZ

MAX_ENROLL_S = 60.0  # at most this much of a recording is used
STYLE_FILE = "style.yaml"
CHECKPOINT_FILE = "model.safetensors"
LICENCE = "the enrolled person's own recording (not redistributed)"


def model_and_style(model: str | None) -> tuple[Path, StyleFile | None]:
    """The checkpoint and the style a ``--model`` option means.

    A folder is a personal model: its ``model.safetensors`` if present, else the packaged
    checkpoint, with its ``style.yaml``. A file is a checkpoint without a style; None is the
    packaged checkpoint.

    Raises:
        StyleError: a folder without a readable ``style.yaml``.
    """
    if model is None:
        return default_checkpoint_path(), None
    path = Path(model)
    if not path.is_dir():
        return path, None
    style = load_style(str(path))
    own = path / CHECKPOINT_FILE
    return (own if own.is_file() else default_checkpoint_path()), style


Synthesizer = Callable[[Clip], np.ndarray]  # a clip's speech -> the model's (T, J) angles


def synthesizer(checkpoint_path: Path, robot: RobotDescription) -> Synthesizer:
    """The model's offline synthesis (seed 0, before the body guard) of a clip's speech."""
    from audio2pose_ros.checkpoints.torch_io import load_checkpoint
    from audio2pose_ros.offline.synthesis import synthesize

    checkpoint = load_checkpoint(checkpoint_path, robot=robot)

    def run(clip: Clip) -> np.ndarray:
        return synthesize(checkpoint, clip.audio, body_margin_m=None)[1]

    return run


@lru_cache(maxsize=4)
def _reference(checkpoint_path: str) -> tuple[Motion, ...]:
    from audio2pose_ros.audio.wav import read_wav
    from audio2pose_ros.robot.description import load_robot

    robot = load_robot()
    run = synthesizer(Path(checkpoint_path), robot)
    motions = []
    for wav in bundled_speech_paths():
        info = ClipInfo(wav.stem, "bundled", wav.name, "public domain", "train")
        empty = np.zeros((0, robot.n_joints))
        angles = run(Clip(info, read_wav(wav)[0], empty, empty.astype(bool)))
        motions.append((angles, np.ones(angles.shape, dtype=bool)))
    return tuple(motions)


def model_reference(checkpoint_path: Path) -> list[Motion]:
    """The model's offline synthesis (seed 0) of the bundled speech: its own figures' source."""
    return list(_reference(str(Path(checkpoint_path).resolve())))


def checkpoint_digest(checkpoint_path: Path) -> str:
    """SHA-256 of a checkpoint file (which model a fitted style was fitted to)."""
    return hashlib.sha256(Path(checkpoint_path).read_bytes()).hexdigest()


def packaged_preset(name: str) -> StyleSettings:
    """The preset ``name``'s settings for the packaged model, as its file keeps them.

    No synthesis (the operator console, which runs neither torch nor the model, offers the
    presets this way); ``python -m audio2pose_ros.style.presets --resolve`` renews them.

    Raises:
        StyleError: no preset of that name, or its kept settings are for another model.
    """
    names = preset_names()
    if name not in names:
        raise StyleError(f"no preset named {name[:40]!r}; the presets: {', '.join(names)}")
    style = load_style(name)
    if style.fitted is None or style.fitted[0] != checkpoint_digest(default_checkpoint_path()):
        raise StyleError(
            f"preset {name} keeps no settings for the packaged model: run "
            "`python -m audio2pose_ros.style.presets --resolve`"
        )
    return style.fitted[1]


def style_settings(
    checkpoint_path: Path, style: StyleFile | None, robot: RobotDescription
) -> StyleSettings:
    """The filter's style settings of ``style`` for the model at ``checkpoint_path``.

    A style fitted to this very checkpoint (enrolment keeps the fit on the person's own speech)
    is used as fitted; otherwise the figures are resolved against the model's motion on the
    bundled speech.
    """
    if style is None or not style.parts:
        return StyleSettings()
    if style.fitted is not None and style.fitted[0] == checkpoint_digest(checkpoint_path):
        return style.fitted[1]
    return resolve(style.parts, model_reference(checkpoint_path), robot)


def fit(
    clips: Sequence[Clip], robot: RobotDescription, synthesize_clip: Synthesizer
) -> tuple[dict[str, PartFigures], StyleSettings]:
    """A person's figures in ``clips`` and the style settings fitted on their own speech.

    The model's motion on the same speech (``synthesize_clip``) is the reference of
    :func:`~audio2pose_ros.style.figures.resolve`: the model's figures on what the person said.
    """
    parts = measure([(c.angles_rad, c.mask) for c in clips], robot)
    reference = []
    for clip in clips:
        angles = synthesize_clip(clip)
        reference.append((angles, np.ones(angles.shape, dtype=bool)))
    return parts, resolve(parts, reference, robot)


def style_overrides(settings: StyleSettings) -> list[str]:
    """``name:=value`` parameter overrides of the filter node for ``settings`` (non-default)."""
    default = StyleSettings()
    return [
        f"{name}:={getattr(settings, name)!r}"
        for name in settings.__dataclass_fields__
        if getattr(settings, name) != getattr(default, name)
    ]


# --- enrolment ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Enrollment:
    """What :func:`enroll` wrote and measured."""

    folder: Path
    style: StyleFile
    settings: StyleSettings  # against the packaged model
    seconds: float  # of the recording used
    elapsed_s: float


def _first_seconds(clips: Sequence[Clip], seconds: float) -> list[Clip]:
    """The clips' first ``seconds`` of motion in order (the last one cut short)."""
    out, left = [], round(seconds * FRAME_RATE_HZ)
    for clip in clips:
        if left <= 0:
            break
        n = min(clip.n_frames, left)
        out.append(Clip(clip.info, clip.audio, clip.angles_rad[:n], clip.mask[:n]))
        left -= n
    return out


def recording_clips(
    source: Path,
    robot: RobotDescription,
    progress: Callable[[str], None],
    max_seconds: float | None = None,
) -> list[Clip]:
    """A recording's clips: a data set folder (any importer's) or one video with speech.

    Of a video only the first ``max_seconds`` are decoded and tracked.

    Raises:
        InputError: missing source, a data set that cannot be read, or a video the importer
            refuses (no audio, unreadable, no face).
    """
    if source.is_dir():
        if not (source / "index.json").is_file():
            raise InputError(f"{source}: a folder must be a data set (it has no index.json)")
        dataset = Dataset.open(source, robot)
        progress(f"reading {len(dataset.clips)} clips of data set {source}")
        return [dataset.load(info.clip_id) for info in dataset.clips]
    if not source.is_file():
        raise InputError(f"{source}: no such file or data set folder")
    from audio2pose_ros.data.importers.video import VideoImportSettings, import_video

    progress(f"tracking face and body in {source.name} (MediaPipe)")
    info = ClipInfo(source.stem[:64] or "recording", "enrolled", source.name, LICENCE, "train")
    settings = VideoImportSettings(body=True, max_seconds=max_seconds)
    clip, _ = import_video(source, info, robot, settings)
    return [clip]


def enroll(
    source: Path,
    folder: Path,
    robot: RobotDescription,
    progress: Callable[[str], None] = print,
    max_seconds: float = MAX_ENROLL_S,
    command: str = "",
) -> Enrollment:
    """Learn a person's style from a recording and write a personal model folder.

    Args:
        source: a video with speech, or a data set folder made by an importer (video, BVH,
            OpenFace).
        folder: the personal model folder to write (created; must not hold a style already).
        robot: joint order, groups and neutral pose.
        progress: called with one line per step.
        max_seconds: at most this much of the recording is measured.
        command: the command line, kept in the style file (how to re-measure it).

    Returns:
        What was written; parts observed for less than ``MIN_PART_S`` are not in the style.

    Raises:
        InputError: unreadable source, or no part observed long enough.
    """
    start = time.monotonic()
    clips = _first_seconds(recording_clips(source, robot, progress, max_seconds), max_seconds)
    seconds = sum(c.n_frames for c in clips) / FRAME_RATE_HZ
    parts = measure([(c.angles_rad, c.mask) for c in clips], robot)
    if not parts:
        raise StyleError(
            f"{source}: no part (head, arms, hip) was observed for {MIN_PART_S:g} s or more in "
            f"the {seconds:.1f} s used: nothing to learn"
        )
    progress(f"measured {', '.join(parts)} over {seconds:.1f} s")
    progress("fitting the style to the packaged model on the recording's speech")
    checkpoint = default_checkpoint_path()
    parts, settings = fit(clips, robot, synthesizer(checkpoint, robot))
    style = StyleFile(
        name=folder.name,
        description=f"personal style measured from {source.name}",
        source=f"{source.name} (first {seconds:.1f} s)",
        command=command or f"audio2pose enroll {source} -o {folder}",
        parts=parts,
        fitted=(checkpoint_digest(checkpoint), settings),
    )
    folder.mkdir(parents=True, exist_ok=True)
    style.write(folder / STYLE_FILE)
    _write_summary(folder, style, settings, seconds)
    elapsed = time.monotonic() - start
    progress(f"wrote {folder / STYLE_FILE} in {elapsed:.0f} s")
    return Enrollment(folder, style, settings, seconds, elapsed)


def _write_summary(folder: Path, style: StyleFile, settings: StyleSettings, seconds: float) -> None:
    lines = [
        f"# Personal style: {style.name}",
        "",
        f"Measured from {style.source} ({seconds:.1f} s); parts: {', '.join(style.parts)}.",
        "Parts not listed keep the model's own motion.",
        "",
        "Against the packaged model these are the motion filter's style parameters:",
        "",
        *[f"- `{item.replace(':=', ': ')}`" for item in style_overrides(settings)],
        "",
        f"Re-measure: `{style.command}`",
        "",
    ]
    (folder / "ENROLLMENT.md").write_text("\n".join(lines), encoding="utf-8")

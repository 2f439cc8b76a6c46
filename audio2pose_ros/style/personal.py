"""Personal models: a person's style learned from a recording (``audio2pose enroll``), and using it.

A personal model is a folder::

    me/
      style.yaml         the person's figures per observed part (audio2pose_ros.style.figures)
      model.safetensors  the packaged model with the person's arm noise, when it was fitted
      ENROLLMENT.md      what was measured, from what, and the settings against the model

It runs ``model.safetensors`` when present, else the packaged model, with the person's style:
every ``--model`` option takes such a folder (:func:`model_and_style`), and the style resolves
into the motion filter's style parameters against the model's own figures
(:func:`style_settings`).

What is fitted (:func:`fit_personal`): the style (per-part size, tempo, arm rest and height);
and, where the arms are seen, the arms' sampling temperature (:func:`fit_arms_noise`, seed
003's subject-dependent model as a fine-tune of one number, without retraining). The default
model's arms are calm on purpose (a person in conversation); a style's size scales that calm
motion about the robot's neutral pose, which the model's arms rest 0.4 to 0.6 rad away from,
so sizes above 2 pin joints at their limits (at 3, both shoulder rolls in every frame of the
lecture) and stay too slow. The model's own noise makes its arms larger and livelier together,
as a lively person's are: on the lecture (enrolled on its first 32 s, scored on the other 41 s)
the arms' H speed / accel / size ratio went from 0.32 / 0.36 / 0.25 with the style alone to
0.17 / 0.18 / 0.45 (the default: 0.38 / 0.35 / 0.14). A style's tempo fitted on top of the noise
slowed it again to the person's still moments, and leaving the tempo out would miss a person
who moves slowly; so the fit keeps, of the style alone, the noise with the arms' rest and
height, and the noise with the whole style, the one closest to the person's own motion on the
recording (:func:`motion_distance`). 60 s of one person hold too little to retrain the model's
speech-to-motion mapping, and neither the noise nor the style can make the motion less safe:
the sampler's step bounds, the limiter and the body guard stay as they are.

:func:`enroll` is the library entry the console calls; ``audio2pose enroll`` its command line.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import time
from collections.abc import Callable, Collection, Iterable, Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from audio2pose_ros.data.dataset import Clip, ClipInfo, Dataset
from audio2pose_ros.errors import InputError
from audio2pose_ros.motion.style import StyleSettings, style_trajectory
from audio2pose_ros.resources import bundled_speech_paths, default_checkpoint_path
from audio2pose_ros.robot.description import RobotDescription
from audio2pose_ros.style.figures import (
    MIN_PART_S,
    Motion,
    PartFigures,
    StyleError,
    StyleFile,
    _derivatives,
    load_style,
    measure,
    measure_part,
    preset_names,
    resolve,
    style_loss,
)
from audio2pose_ros.timebase import FRAME_RATE_HZ, SAMPLES_PER_FRAME, WINDOW_SAMPLES

if TYPE_CHECKING:
    from audio2pose_ros.checkpoints.torch_io import Checkpoint

MAX_ENROLL_S = 60.0  # at most this much of a recording is used
ARMS_NOISE_FACTORS = (1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0)  # arm temperature factors tried
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

    return checkpoint_synthesizer(load_checkpoint(checkpoint_path, robot=robot))


def checkpoint_synthesizer(checkpoint: Checkpoint) -> Synthesizer:
    """A loaded model's offline synthesis (seed 0, before the body guard) of a clip's speech."""
    from audio2pose_ros.offline.synthesis import synthesize

    def run(clip: Clip) -> np.ndarray:
        return synthesize(checkpoint, clip.audio, body_margin_m=None)[1]

    return run


class Synthesizers:
    """Each model's synthesis of each clip, computed once.

    A personal fit synthesizes the same speech with the same models several times (the noise
    factors, the style fits, the final choice).
    """

    def __init__(self) -> None:
        self._done: dict[tuple[int, int], np.ndarray] = {}
        self._kept: list[object] = []  # the keys' objects stay alive, so their ids stay unique

    def of(self, checkpoint: Checkpoint) -> Synthesizer:
        """The synthesis of ``checkpoint`` (:func:`checkpoint_synthesizer`), remembered."""
        run = checkpoint_synthesizer(checkpoint)

        def remembered(clip: Clip) -> np.ndarray:
            key = (id(checkpoint), id(clip))
            if key not in self._done:
                self._kept += [checkpoint, clip]
                self._done[key] = run(clip)
            return self._done[key]

        return remembered


def with_arms_noise(checkpoint: Checkpoint, factor: float) -> Checkpoint | None:
    """``checkpoint`` whose arms sample at ``factor`` times their temperature (no retraining).

    Only a model that samples its joints in two parts with settable sampling settings
    (``live_groups``, :meth:`~audio2pose_ros.models.live_groups.LiveGroups.with_sampling`) and
    holds all arm joints in its second part; for others None. The hip in that part keeps its
    temperature.
    """
    model = checkpoint.model
    config = getattr(model, "config", None)
    groups = getattr(model, "groups", None)
    with_sampling = getattr(model, "with_sampling", None)
    if not callable(with_sampling) or config is None or groups is None:
        return None
    arms = checkpoint.robot.group_mask("arms")
    second = np.asarray(groups[1])
    if len(groups) != 2 or not arms[second].any() or arms[np.asarray(groups[0])].any():
        return None
    base = np.broadcast_to(np.asarray(config.second_temperature, dtype=np.float64), second.shape)
    temperatures = tuple(float(t) for t in base * np.where(arms[second], factor, 1.0))
    return dataclasses.replace(checkpoint, model=with_sampling(second_temperature=temperatures))


def fit_arms_noise(
    clips: Sequence[Clip],
    person: PartFigures,
    checkpoint: Checkpoint,
    synthesizers: Synthesizers | None = None,
) -> tuple[float, Checkpoint]:
    """The arms' sampling temperature factor whose motion on ``clips``' speech fits ``person``.

    Of :data:`ARMS_NOISE_FACTORS`, the factor whose arm figures on the person's own speech have
    the smallest :func:`~audio2pose_ros.style.figures.style_loss` to the person's (upper speed
    and acceleration deciles and size); the default model's arms are calm on purpose, and the
    model's own noise reaches a lively person's size and pace where a style's size, a scale of
    the calm motion, cannot (module docstring). Returns (1, ``checkpoint``) for a model without
    per-part sampling (:func:`with_arms_noise`).
    """
    synthesizers = synthesizers or Synthesizers()
    best: tuple[float, float, Checkpoint] = (math.inf, 1.0, checkpoint)
    for factor in ARMS_NOISE_FACTORS:
        candidate = checkpoint if factor == 1.0 else with_arms_noise(checkpoint, factor)
        if candidate is None:
            break
        run = synthesizers.of(candidate)
        motions = [(angles, np.ones(angles.shape, dtype=bool)) for angles in map(run, clips)]
        model = measure_part(motions, checkpoint.robot, "arms")
        if model is None:
            break
        loss = style_loss(person, model)
        if loss < best[0]:
            best = (loss, factor, candidate)
    return best[1], best[2]


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


def fit_style(
    parts: dict[str, PartFigures],
    clips: Sequence[Clip],
    robot: RobotDescription,
    synthesize_clip: Synthesizer,
    paced: Collection[str] = (),
) -> StyleSettings:
    """The style settings that bring a model's motion to the person's figures ``parts``.

    The model's motion on the person's own speech in ``clips`` (``synthesize_clip``) is the
    reference of :func:`~audio2pose_ros.style.figures.resolve` (``paced``: parts whose tempo
    and size it leaves at 1): the model's figures on what the person said.
    """
    reference = []
    for clip in clips:
        angles = synthesize_clip(clip)
        reference.append((angles, np.ones(angles.shape, dtype=bool)))
    return resolve(parts, reference, robot, paced=paced)


@dataclass(frozen=True)
class PersonalFit:
    """A personal model fitted to a recording (:func:`fit_personal`).

    Attributes:
        parts: the person's figures per observed part.
        settings: the style settings against ``checkpoint``.
        checkpoint: the model with the person's arm noise (the given one when ``arms_noise``
            is 1).
        arms_noise: the factor of the arms' sampling temperature.
        style_alone: the style settings fitted to the given model itself (what a running graph
            that keeps its model applies).
    """

    parts: dict[str, PartFigures]
    settings: StyleSettings
    checkpoint: Checkpoint
    arms_noise: float
    style_alone: StyleSettings


def fit_personal(
    clips: Sequence[Clip],
    robot: RobotDescription,
    checkpoint: Checkpoint,
    synthesizers: Synthesizers | None = None,
) -> PersonalFit:
    """A person's model: the arms' sampling noise (when the arms are seen) and the style.

    Three candidates for the arms: the style alone on ``checkpoint``; the model with the
    person's arm noise (:func:`fit_arms_noise`) with only the arms' rest and height styled
    (``paced``); and that model with the whole style on top. The one closest to the person's
    own motion on the same speech (:func:`motion_distance`) wins. A style's tempo fitted on top
    of the noise slows the motion down to a person's still moments between gestures (the
    lecture), and leaving it out misses a person who moves slowly: the recording decides.
    ``synthesizers`` lets a caller that synthesizes the same clips share them (the evaluation).
    """
    real = [(c.angles_rad, c.mask) for c in clips]
    parts = measure(real, robot)  # the person's figures, the same for every candidate
    synthesizers = synthesizers or Synthesizers()
    alone = fit_style(parts, clips, robot, synthesizers.of(checkpoint))
    plain = PersonalFit(parts, alone, checkpoint, 1.0, alone)
    if "arms" not in parts:
        return plain
    factor, noisier = fit_arms_noise(clips, parts["arms"], checkpoint, synthesizers)
    if factor == 1.0:
        return plain
    run = synthesizers.of(noisier)
    candidates = [
        plain,
        PersonalFit(parts, fit_style(parts, clips, robot, run, ("arms",)), noisier, factor, alone),
        PersonalFit(parts, fit_style(parts, clips, robot, run), noisier, factor, alone),
    ]

    def distance(candidate: PersonalFit) -> float:
        synthesize_clip = synthesizers.of(candidate.checkpoint)
        motion = []
        for clip in clips:
            angles = synthesized_over_clip(clip, synthesize_clip)
            styled = style_trajectory(robot, candidate.settings, angles, FRAME_RATE_HZ)
            motion.append((styled, clip.mask))
        return motion_distance(real, motion, robot, "arms")

    return min(candidates, key=distance)


def synthesized_over_clip(clip: Clip, synthesize_clip: Synthesizer) -> np.ndarray:
    """The model's angles of a clip's speech, as many frames as the clip (last pose held)."""
    angles = synthesize_clip(clip)
    n = min(len(angles), clip.n_frames)
    return np.vstack([angles[:n], np.repeat(angles[n - 1 :], clip.n_frames - n, axis=0)])


def motion_distance(
    real: Sequence[Motion], model: Sequence[Motion], robot: RobotDescription, part: str
) -> float:
    """How far ``model``'s motion of ``part`` is from ``real``, as the held-out evaluation scores.

    The Hellinger distances of joint speed and acceleration (the bins of
    :mod:`~audio2pose_ros.learning.metrics`, joints pooled) plus the absolute log of the size
    ratio, over the frames ``real`` knows (``model`` carries the same masks and lengths).
    """
    from audio2pose_ros.learning.metrics import (
        ACCELERATION_BINS_RAD_S2,
        SPEED_BINS_RAD_S,
        hellinger,
    )

    joints = [int(j) for j in np.flatnonzero(robot.group_mask(part))]
    total = 0.0
    for order, bins in ((1, SPEED_BINS_RAD_S), (2, ACCELERATION_BINS_RAD_S2)):
        counts = []
        for motions in (real, model):
            values = [_derivatives(motions, j, order, FRAME_RATE_HZ) for j in joints]
            counts.append(np.histogram(np.concatenate(values), bins)[0])
        total += hellinger(counts[0], counts[1])
    sizes = [measure_part(m, robot, part, min_seconds=0.0) for m in (real, model)]
    if sizes[0] is None or sizes[1] is None:
        return math.inf
    return total + abs(math.log(sizes[1].std_rad / sizes[0].std_rad))


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
    settings: StyleSettings  # the style alone, against the packaged model (a running graph's)
    seconds: float  # of the recording used
    elapsed_s: float
    arms_noise: float = 1.0  # the personal checkpoint's arm noise factor (1: none written)


def _first_seconds(clips: Iterable[Clip], seconds: float) -> list[Clip]:
    """The clips' first ``seconds`` of motion in order (the last one cut short), as copies.

    A clip is taken from ``clips`` only while seconds are missing (a generator that loads them
    loads no more). A cut clip keeps the audio of its frames only (frame ``i``'s window ends at
    sample ``160 i + 400``), and what is kept is copied, so the rest of a long clip is freed.
    """
    out, left, source = [], round(seconds * FRAME_RATE_HZ), iter(clips)
    while left > 0 and (clip := next(source, None)) is not None:
        n = min(clip.n_frames, left)
        samples = SAMPLES_PER_FRAME * (n - 1) + WINDOW_SAMPLES
        audio, angles, mask = clip.audio[:samples], clip.angles_rad[:n], clip.mask[:n]
        out.append(Clip(clip.info, audio.copy(), angles.copy(), mask.copy()))
        left -= n
    return out


def recording_clips(
    source: Path,
    robot: RobotDescription,
    progress: Callable[[str], None],
    max_seconds: float = MAX_ENROLL_S,
) -> list[Clip]:
    """A recording's first ``max_seconds``: of a data set folder (any importer's) or a video.

    Only that much is read: a data set's clips are loaded in order until it is reached, each
    no further than that (:meth:`~audio2pose_ros.data.dataset.Dataset.load`); of a video, the
    audio and frames after it are not decoded (:func:`~.importers.video.import_video` with
    ``max_seconds``), and frames are scaled down to what MediaPipe needs.

    Raises:
        InputError: missing source, a data set that cannot be read, or a video the importer
            refuses (no audio, no video, frames too large, unreadable, no face).
    """
    if source.is_dir():
        if not (source / "index.json").is_file():
            raise InputError(f"{source}: a folder must be a data set (it has no index.json)")
        dataset = Dataset.open(source, robot)
        progress(f"reading the first {max_seconds:g} s of data set {source}")
        frames = round(max_seconds * FRAME_RATE_HZ)  # of each clip, at most this much is read
        clips = (dataset.load(info.clip_id, max_frames=frames) for info in dataset.clips)
        return _first_seconds(clips, max_seconds)
    if not source.is_file():
        raise InputError(f"{source}: no such file or data set folder")
    from audio2pose_ros.data.importers.video import VideoImportSettings, import_video

    progress(f"tracking face and body in the first {max_seconds:g} s of {source.name} (MediaPipe)")
    info = ClipInfo(source.stem[:64] or "recording", "enrolled", source.name, LICENCE, "train")
    settings = VideoImportSettings(body=True, max_seconds=max_seconds)
    clip, _ = import_video(source, info, robot, settings)
    return _first_seconds([clip], max_seconds)


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
    clips = recording_clips(source, robot, progress, max_seconds)
    seconds = sum(c.n_frames for c in clips) / FRAME_RATE_HZ
    parts = measure([(c.angles_rad, c.mask) for c in clips], robot)
    if not parts:
        raise StyleError(
            f"{source}: no part (head, arms, hip) was observed for {MIN_PART_S:g} s or more in "
            f"the {seconds:.1f} s used: nothing to learn"
        )
    progress(f"measured {', '.join(parts)} over {seconds:.1f} s")
    progress("fitting the arms' noise and the style to the packaged model on the recorded speech")
    from audio2pose_ros.checkpoints.torch_io import load_checkpoint, save_checkpoint

    checkpoint = default_checkpoint_path()
    personal = fit_personal(clips, robot, load_checkpoint(checkpoint, robot=robot))
    folder.mkdir(parents=True, exist_ok=True)
    own = folder / CHECKPOINT_FILE
    own.unlink(missing_ok=True)  # a model of an earlier enrolment (--force)
    if personal.arms_noise != 1.0:
        checkpoint = save_checkpoint(own, personal.checkpoint)
    style = StyleFile(
        name=folder.name,
        description=f"personal style measured from {source.name}",
        source=f"{source.name} (first {seconds:.1f} s)",
        command=command or f"audio2pose enroll {source} -o {folder}",
        parts=personal.parts,
        fitted=(checkpoint_digest(checkpoint), personal.settings),
    )
    style.write(folder / STYLE_FILE)
    _write_summary(folder, style, personal.settings, seconds, personal.arms_noise)
    elapsed = time.monotonic() - start
    progress(f"wrote {folder / STYLE_FILE} in {elapsed:.0f} s")
    return Enrollment(folder, style, personal.style_alone, seconds, elapsed, personal.arms_noise)


def _write_summary(
    folder: Path, style: StyleFile, settings: StyleSettings, seconds: float, arms_noise: float
) -> None:
    model = (
        f"The packaged model with the arms' sampling noise {arms_noise:g} times as large "
        f"({CHECKPOINT_FILE}); against it these"
        if arms_noise != 1.0
        else "Against the packaged model these"
    )
    lines = [
        f"# Personal style: {style.name}",
        "",
        f"Measured from {style.source} ({seconds:.1f} s); parts: {', '.join(style.parts)}.",
        "Parts not listed keep the model's own motion.",
        "",
        f"{model} are the motion filter's style parameters:",
        "",
        *[f"- `{item.replace(':=', ': ')}`" for item in style_overrides(settings)],
        "",
        f"Re-measure: `{style.command}`",
        "",
    ]
    (folder / "ENROLLMENT.md").write_text("\n".join(lines), encoding="utf-8")

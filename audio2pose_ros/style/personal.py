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
who moves slowly; so the fit tries the style alone, the noise with the arms' rest and height,
and the noise with the whole style, and cross-validation inside the recording
(:mod:`~audio2pose_ros.style.crossval`) chooses among them and how far from the default to go,
part by part, keeping the default where none comes closer to the person on stretches it did not
fit (:func:`fit_personal`). 60 s of one person hold too little to retrain the model's
speech-to-motion mapping, and neither the noise nor the style can make the motion less safe:
the sampler's step bounds, the limiter and the body guard stay as they are.

:func:`enroll` is the library entry the console calls; ``audio2pose enroll`` its command line.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from audio2pose_ros.checkpoints.switch import CHECKPOINT_FILE, STYLE_FILE
from audio2pose_ros.data.dataset import Clip, ClipInfo, Dataset
from audio2pose_ros.errors import InputError
from audio2pose_ros.motion.style import IDENTITY, StyleSettings, style_trajectory
from audio2pose_ros.resources import bundled_speech_paths, default_checkpoint_path
from audio2pose_ros.robot.description import RobotDescription
from audio2pose_ros.style.crossval import (
    FOLD_MIN_S,
    STRENGTHS,
    Measures,
    PartVerdict,
    Piece,
    choose,
    cut,
    folds,
    merged,
    noise_at,
    part_measures,
    toward,
)
from audio2pose_ros.style.figures import (
    MIN_PART_S,
    Motion,
    PartFigures,
    StyleError,
    StyleFile,
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
    models = noise_models(checkpoint)
    motions = {
        factor: [_all_known(synthesized_over_clip(c, synthesizers.of(model))) for c in clips]
        for factor, model in models.items()
    }
    factor = closest_noise(person, motions, checkpoint.robot)
    return factor, models[factor]


def noise_models(checkpoint: Checkpoint) -> dict[float, Checkpoint]:
    """:data:`ARMS_NOISE_FACTORS` -> ``checkpoint`` with that arm noise (:func:`with_arms_noise`).

    Only the factor 1 (``checkpoint`` itself) for a model without per-part sampling.
    """
    models = {1.0: checkpoint}
    for factor in ARMS_NOISE_FACTORS[1:]:
        candidate = with_arms_noise(checkpoint, factor)
        if candidate is None:
            break
        models[factor] = candidate
    return models


def closest_noise(
    person: PartFigures, motions: Mapping[float, Sequence[Motion]], robot: RobotDescription
) -> float:
    """The factor of ``motions`` (factor -> the model's motion) whose arms fit ``person`` best.

    By :func:`~audio2pose_ros.style.figures.style_loss`; the first factor on a tie, 1 when no
    motion shows the arms long enough.
    """
    best = (math.inf, 1.0)
    for factor, motion in motions.items():
        model = measure_part(motion, robot, "arms", min_seconds=FOLD_MIN_S)
        if model is not None and (loss := style_loss(person, model)) < best[0]:
            best = (loss, factor)
    return best[1]


def _all_known(angles: np.ndarray) -> Motion:
    return angles, np.ones(angles.shape, dtype=bool)


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


ARMS_FITS = ("style", "noise + rest", "noise + style")  # the ways of fitting the arms
CONTEXT_FRAMES = 100  # a held-out stretch is styled from this many frames before it


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
        verdicts: per observed part, what cross-validation decided for ``settings`` and
            ``checkpoint`` (:class:`~audio2pose_ros.style.crossval.PartVerdict`).
        alone_verdicts: the same for ``style_alone`` (the arms without their own noise).
    """

    parts: dict[str, PartFigures]
    settings: StyleSettings
    checkpoint: Checkpoint
    arms_noise: float
    style_alone: StyleSettings
    verdicts: dict[str, PartVerdict] = dataclasses.field(default_factory=dict)
    alone_verdicts: dict[str, PartVerdict] = dataclasses.field(default_factory=dict)

    @property
    def learned(self) -> list[str]:
        """The parts whose learned style is used (the others keep the default)."""
        return [part for part, v in self.verdicts.items() if not v.kept_default]

    def report(self) -> list[str]:
        """One line per part: the expected gain with its spread, or why it kept the default."""
        lines = [v.line() for v in self.verdicts.values()]
        for part, v in self.alone_verdicts.items():
            if v != self.verdicts.get(part):
                lines.append(f"without a model of its own (the console's live style): {v.line()}")
        return lines


_Fits = dict[str, tuple[float, StyleSettings]]  # way of fitting -> (arms noise, style settings)


def _fits(
    person: Mapping[str, PartFigures],
    references: Mapping[float, Sequence[Motion]],
    robot: RobotDescription,
) -> _Fits:
    """The full fits of ``person``'s figures against the model's motion of each arm noise.

    "style": the style against the default's motion (:func:`~audio2pose_ros.style.figures.
    resolve`); for the arms also the person's noise (:func:`closest_noise`) with only the
    arms' rest and height styled ("noise + rest"), and with the whole arm style ("noise +
    style"). The style's tempo on top of the noise slows the motion down to a person's still
    moments between gestures (the lecture), and leaving it out misses a person who moves
    slowly: cross-validation decides.
    """
    out = {"style": (1.0, resolve(person, references[1.0], robot, min_seconds=FOLD_MIN_S))}
    if "arms" in person and len(references) > 1:
        factor = closest_noise(person["arms"], references, robot)
        if factor != 1.0:
            arms = {"arms": person["arms"]}
            out["noise + rest"] = (
                factor,
                resolve(arms, references[factor], robot, paced=("arms",), min_seconds=FOLD_MIN_S),
            )
            whole = resolve(arms, references[factor], robot, min_seconds=FOLD_MIN_S)
            out["noise + style"] = (factor, whole)
    return out


def _ways(part: str, fits: _Fits) -> list[str]:
    return [w for w in fits if part == "arms" or w == "style"]


def _at(
    fits: _Fits, way: str, strength: float, part: str, raises: Mapping[float, float | None]
) -> tuple[float, StyleSettings]:
    """The arms' noise and the style of ``part``'s fit ``way`` at ``strength`` (0: default).

    ``raises``: per arm noise factor, how high the model's own arms rise (the 1st percentile of
    the shoulder pitch), where :func:`~audio2pose_ros.style.crossval.toward` starts the height
    limit.
    """
    factor, settings = fits[way]
    noise = noise_at(factor, strength, ARMS_NOISE_FACTORS)
    return noise, toward(settings, strength, part, raises.get(noise))


def _held_out(
    synthesized: Mapping[float, Sequence[np.ndarray]],
    real: Sequence[Motion],
    pieces: Sequence[Piece],
    factor: float,
    settings: StyleSettings,
    robot: RobotDescription,
) -> list[Motion]:
    """The model's motion of the ``pieces`` with the arm noise ``factor``, styled as it runs.

    Each piece is styled from :data:`CONTEXT_FRAMES` before it (the causal filters settle)
    and carries the real motion's mask.
    """
    out = []
    for c, a, b in pieces:
        start = max(a - CONTEXT_FRAMES, 0)
        styled = style_trajectory(robot, settings, synthesized[factor][c][start:b], FRAME_RATE_HZ)
        out.append((styled[a - start :], real[c][1][a:b]))
    return out


def fit_personal(
    clips: Sequence[Clip],
    robot: RobotDescription,
    checkpoint: Checkpoint,
    synthesizers: Synthesizers | None = None,
) -> PersonalFit:
    """A person's model, part by part no further from the person than the default is.

    Cross-validated inside the recording (:mod:`~audio2pose_ros.style.crossval`): for each fold
    (:func:`~audio2pose_ros.style.crossval.folds`), every way of fitting (:func:`_fits`) is
    fitted to the person's figures on the training stretches and scored, at each strength
    between the default and the full fit, on the held-out stretch against the default. Per
    part, :func:`~audio2pose_ros.style.crossval.choose` takes the way and strength or keeps the
    default; the result is the full fit on the whole recording taken that far from the default.
    ``synthesizers`` lets a caller that synthesizes the same clips share them (the evaluation).
    """
    real = [(c.angles_rad, c.mask) for c in clips]
    parts = measure(real, robot)  # the person's figures, the same for every candidate
    synthesizers = synthesizers or Synthesizers()
    models = noise_models(checkpoint) if "arms" in parts else {1.0: checkpoint}
    synthesized = {
        factor: [synthesized_over_clip(c, synthesizers.of(model)) for c in clips]
        for factor, model in models.items()
    }
    references = {f: [_all_known(a) for a in angles] for f, angles in synthesized.items()}
    raises = {}
    for factor, motion in references.items():
        arms = measure_part(motion, robot, "arms", min_seconds=0.0)
        raises[factor] = arms.raise_p1_rad if arms is not None else None
    default_scores: dict[str, list[Measures]] = {part: [] for part in parts}
    trials: dict[str, dict[tuple[str, float], list[Measures]]] = {part: {} for part in parts}
    for training, held in folds([c.n_frames for c in clips]):
        train_real, held_real = cut(real, training), cut(real, held)
        person = {}
        for part in parts:
            figures = measure_part(train_real, robot, part, min_seconds=FOLD_MIN_S)
            if figures is not None and measure_part(held_real, robot, part, min_seconds=1.0):
                person[part] = figures
        fits = _fits(person, {f: cut(m, training) for f, m in references.items()}, robot)
        default = _held_out(synthesized, real, held, 1.0, IDENTITY, robot)
        for part in person:
            default_scores[part].append(part_measures(held_real, default, robot, part))
            for way in _ways(part, fits):
                for strength in STRENGTHS:
                    factor, settings = _at(fits, way, strength, part, raises)
                    motion = _held_out(synthesized, real, held, factor, settings, robot)
                    scores = trials[part].setdefault((way, strength), [])
                    scores.append(part_measures(held_real, motion, robot, part))
    verdicts, alone = {}, {}
    for part, figures in parts.items():
        complete = {k: v for k, v in trials[part].items() if len(v) == len(default_scores[part])}
        verdicts[part] = choose(part, default_scores[part], complete, figures.seconds)
        plain = {k: v for k, v in complete.items() if k[0] == "style"}
        alone[part] = choose(part, default_scores[part], plain, figures.seconds)
    fits = _fits(parts, references, robot)

    def settled(chosen: Mapping[str, PartVerdict]) -> tuple[float, StyleSettings]:
        styles, factor = {}, 1.0
        for part, verdict in chosen.items():
            if verdict.kept_default:
                continue
            way = verdict.fit if verdict.fit in fits else "style"
            noise, styles[part] = _at(fits, way, verdict.strength, part, raises)
            factor = noise if part == "arms" else factor
        return factor, merged(styles)

    factor, settings = settled(verdicts)
    _, style_alone = settled(alone)
    return PersonalFit(parts, settings, models[factor], factor, style_alone, verdicts, alone)


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
    ratio, over the frames ``real`` knows (``model`` carries the same masks and lengths):
    :func:`~audio2pose_ros.style.crossval.part_measures` in total.
    """
    return part_measures(real, model, robot, part).total


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
    report: tuple[str, ...] = ()  # per part: the expected gain, or why it kept the default
    # per observed part, what cross-validation decided for the personal model (its checkpoint,
    # if written, with the style fitted to it)
    verdicts: tuple[PartVerdict, ...] = ()


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
    report = tuple(personal.report())
    for line in report:
        progress(line)
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
        parts={part: personal.parts[part] for part in personal.learned},
        fitted=(checkpoint_digest(checkpoint), personal.settings),
    )
    style.write(folder / STYLE_FILE)
    _write_summary(folder, style, personal.settings, seconds, personal.arms_noise, report)
    elapsed = time.monotonic() - start
    progress(f"wrote {folder / STYLE_FILE} in {elapsed:.0f} s")
    return Enrollment(
        folder,
        style,
        personal.style_alone,
        seconds,
        elapsed,
        personal.arms_noise,
        report,
        tuple(personal.verdicts.values()),
    )


def _write_summary(
    folder: Path,
    style: StyleFile,
    settings: StyleSettings,
    seconds: float,
    arms_noise: float,
    report: Sequence[str],
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
        f"Measured from {style.source} ({seconds:.1f} s); parts learned: "
        f"{', '.join(style.parts) or 'none'}.",
        "Parts not listed keep the model's own motion.",
        "",
        "Fitted on part of the recording and scored on the rest, over several folds:",
        "",
        *[f"- {line}" for line in report],
        "",
        f"{model} are the motion filter's style parameters:",
        "",
        *[f"- `{item.replace(':=', ': ')}`" for item in style_overrides(settings)],
        "",
        f"Re-measure: `{style.command}`",
        "",
    ]
    (folder / "ENROLLMENT.md").write_text("\n".join(lines), encoding="utf-8")

"""Does enrolment predict a person's motion? Default (SI) vs enrolled (SD) vs the real floor.

Seed 003's Table 5.1 compares subject-independent models (trained on other people) with
subject-dependent ones (trained on the same person) on held-out data. Here the subject-dependent
model is the default model with the person's style (:mod:`audio2pose_ros.style.personal`),
enrolled on the first :data:`~audio2pose_ros.style.personal.MAX_ENROLL_S` (at most half) of a
source's clips (:func:`_split`) and scored on the rest; also on the first 10 s and 20 s of that
part (:data:`ENROLL_LENGTHS_S`, what the console's Learn my style records), scored on the same
held-out speech:

- **SI**: the default model's offline synthesis (seed 0) of the held-out clips' speech;
- **SD**: what ``audio2pose enroll`` makes of the first part and ``--model`` runs: the personal
  fit (:func:`~audio2pose_ros.style.personal.fit_personal`, cross-validated inside the
  enrolment, part by part the default where no fit comes closer; the arms' sampling noise where
  the arms are seen, and the style), the synthesis of the held-out speech by its model (the personal
  checkpoint when the noise was fitted, else the default), with its style applied as the live
  filter applies it;
- **floor**: the real held-out motion's first half of clips against its second (realism's
  split half), what two stretches of the same person differ by;
- **real enrolment part**: the person's own enrolment motion against the held-out motion: how
  far the stretch enrolled on predicts the rest at all (no beat consistency: other speech).

For each part the source observes (head, arms, hip), against the real held-out motion (its known
frames only): the Hellinger distances of joint speed and acceleration (seed 003 section 5.3,
the bins of :mod:`~audio2pose_ros.learning.metrics`), the size ratio (part std, model / real),
how many speed and acceleration percentiles (p50, p90, p99 per joint) lie within 25 % of real
(:func:`~audio2pose_ros.learning.realism.percentile_agreement`) with the lowest and highest
ratio, and the beat consistency (EMAGE's BC, :mod:`~audio2pose_ros.learning.realism`). Goals
(per source): SD at least as close as SI on every measure, or SI kept (:func:`holds`, with the
enrolment's verdict, :func:`verdict_note`); SD percentiles within 25 %, H <= 0.12, std 0.8 to
1.25 x.

A data set's clips are grouped into sources by their ids (:func:`source_of`); a data set given
as ``NAME=DATASET`` (:func:`source_spec`) is one source, whatever its clip ids: one person's
import of many recordings, such as GRID speaker s1's sentences. Each clip's speech is
synthesized once by each model for the whole evaluation
(:class:`~audio2pose_ros.style.personal.Synthesizers`, shared with the personal fit).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from audio2pose_ros.data.dataset import Clip, Dataset
from audio2pose_ros.learning.metrics import ACCELERATION_BINS_RAD_S2, SPEED_BINS_RAD_S, hellinger
from audio2pose_ros.learning.realism import (
    audio_onsets,
    percentile_agreement,
    pooled_beat_consistency,
    speed_percentiles,
)
from audio2pose_ros.motion.style import style_trajectory
from audio2pose_ros.resources import default_checkpoint_path
from audio2pose_ros.robot.description import RobotDescription
from audio2pose_ros.style.figures import Motion, _derivatives, measure_part
from audio2pose_ros.style.personal import (
    PersonalFit,
    Synthesizers,
    fit_personal,
    style_overrides,
    synthesized_over_clip,
)
from audio2pose_ros.timebase import FRAME_RATE_HZ

if TYPE_CHECKING:
    from audio2pose_ros.checkpoints.torch_io import Checkpoint

PARTS: tuple[str, ...] = ("head", "arms", "hip")
SCORE_MIN_S = 1.0  # a scored part needs this much known motion
SOURCE_NAME = re.compile(r"[A-Za-z0-9_-]{1,64}")


@dataclass(frozen=True)
class SourceSpec:
    """A data set to evaluate; with a ``name``, all its clips are that one source."""

    path: Path
    name: str | None = None


def source_spec(text: str) -> SourceSpec:
    """``DATASET`` or ``NAME=DATASET`` (``NAME``: letters, digits, ``_`` and ``-``).

    Text that names an existing path, or whose part before ``=`` is not such a name, is a data
    set path as it stands.
    """
    name, sep, path = text.partition("=")
    if sep and path and SOURCE_NAME.fullmatch(name) and not Path(text).exists():
        return SourceSpec(Path(path), name)
    return SourceSpec(Path(text))


@dataclass(frozen=True)
class Row:
    """One line of the table: a source, a part, a method and its measures."""

    source: str
    part: str
    method: str
    h_speed: float
    h_accel: float
    std_ratio: float
    inside: int
    total: int
    lowest: float
    highest: float
    beat: float
    note: str = "-"  # an enrolled row: at least as close as the default, and the verdict


def source_of(clip_id: str) -> str:
    """The source a clip belongs to: its id up to the first ``_`` (obama, grid, lecture)."""
    return re.split(r"[_\d]", clip_id, maxsplit=1)[0] or clip_id


def _part(motions: Sequence[Motion], joints: np.ndarray) -> list[Motion]:
    return [(a[:, joints], k[:, joints]) for a, k in motions]


def _hellinger(real: Sequence[Motion], model: Sequence[Motion], order: int) -> float:
    bins = SPEED_BINS_RAD_S if order == 1 else ACCELERATION_BINS_RAD_S2
    counts = []
    for motions in (real, model):
        values = np.concatenate(
            [_derivatives(motions, j, order, FRAME_RATE_HZ) for j in range(motions[0][0].shape[1])]
        )
        counts.append(np.histogram(values, bins)[0])
    return hellinger(counts[0], counts[1])


def _row(
    source: str,
    part: str,
    method: str,
    real: Sequence[Motion],
    model: Sequence[Motion],
    onsets: Sequence[np.ndarray],
    robot: RobotDescription,
) -> Row:
    joints = robot.group_mask(part)
    real_p, model_p = _part(real, joints), _part(model, joints)
    agreement = percentile_agreement(speed_percentiles(model_p), speed_percentiles(real_p))
    real_fig = measure_part(real, robot, part, FRAME_RATE_HZ, SCORE_MIN_S)
    model_fig = measure_part(model, robot, part, FRAME_RATE_HZ, SCORE_MIN_S)
    ratio = (
        model_fig.std_rad / real_fig.std_rad
        if real_fig is not None and model_fig is not None
        else float("nan")
    )
    return Row(
        source,
        part,
        method,
        _hellinger(real_p, model_p, 1),
        _hellinger(real_p, model_p, 2),
        ratio,
        agreement.inside,
        agreement.total,
        agreement.lowest,
        agreement.highest,
        pooled_beat_consistency(onsets, model_p, range(len(model_p))),
    )


def _cut(clip: Clip, frame: int) -> tuple[Clip, Clip]:
    """``clip`` cut in two at ``frame`` (its audio with it)."""
    audio = frame * (clip.audio.size // max(clip.n_frames, 1))

    def piece(start: int, stop: int | None, a0: int, a1: int | None) -> Clip:
        return Clip(
            clip.info, clip.audio[a0:a1], clip.angles_rad[start:stop], clip.mask[start:stop]
        )

    return piece(0, frame, 0, audio), piece(frame, None, audio, None)


def _split(clips: Sequence[Clip], enroll_s: float) -> tuple[list[Clip], list[Clip]]:
    """Enrol on whole clips from the start, at most ``enroll_s`` and half the frames.

    When the whole clips that fit hold less than half of that (a single clip, or a long clip
    second), the next clip is cut in two at it.
    """
    total = sum(c.n_frames for c in clips)
    budget = round(min(enroll_s * FRAME_RATE_HZ, total / 2))
    enrol: list[Clip] = []
    used = 0
    for clip in clips:
        if used + clip.n_frames > budget:
            break
        enrol.append(clip)
        used += clip.n_frames
    rest = list(clips[len(enrol) :])
    if used >= budget / 2 or not rest:
        return enrol, rest
    first, second = _cut(rest[0], budget - used)
    return [*enrol, first], [second, *rest[1:]]


def figure_rows(
    name: str,
    clips: Sequence[Clip],
    robot: RobotDescription,
    synthesize_clip: Callable[[Clip], np.ndarray],
) -> list[str]:
    """Table lines: the source's figures per observed part, then the default model's.

    The model's are of the same speech, over the source's known frames only.
    """
    real = [(c.angles_rad, c.mask) for c in clips]
    model = [(synthesized_over_clip(c, synthesize_clip), c.mask) for c in clips]
    lines = []
    for part in PARTS:
        for who, motions in ((f"{name} (real)", real), ("default model, same speech", model)):
            f = measure_part(motions, robot, part, FRAME_RATE_HZ, SCORE_MIN_S)
            if f is None:
                break
            arms = (
                f"{f.rest_pitch_rad:.2f} / {f.rest_bend_rad:.2f} / {f.raise_p1_rad:.2f}"
                if f.rest_pitch_rad is not None
                else "-"
            )
            lines.append(
                f"| {who} | {part} | {f.seconds:.0f} | {f.std_rad:.3f} | "
                f"{f.speed_deciles_rad_s[4]:.3f} / {f.speed_deciles_rad_s[8]:.3f} | "
                f"{f.accel_deciles_rad_s2[4]:.2f} / {f.accel_deciles_rad_s2[8]:.2f} | {arms} |"
            )
    return lines


FIGURES_HEADER = (
    "| motion | part | s | std (rad) | speed p50 / p90 (rad/s) | accel p50 / p90 (rad/s²) | "
    "arm rest pitch / bend / raise p1 (rad) |\n|---|---|---|---|---|---|---|"
)


ENROLL_LENGTHS_S = (10.0, 20.0)  # shorter enrolments tried besides the longest (the console's)


def enrolment_lengths(enroll_s: float, available_s: float) -> list[float]:
    """The enrolment lengths tried: :data:`ENROLL_LENGTHS_S` below ``enroll_s``, and ``enroll_s``.

    Each at most ``available_s`` (what the source holds for enrolment); lengths that come to
    the same are tried once.
    """
    out: list[float] = []
    for seconds in (*[s for s in ENROLL_LENGTHS_S if s < enroll_s], enroll_s):
        used = min(seconds, available_s)
        if not out or used > out[-1] + 0.5:
            out.append(used)
    return out


def first_seconds(clips: Sequence[Clip], seconds: float) -> list[Clip]:
    """The clips' first ``seconds`` in order, the last one cut short (its audio with it)."""
    out, left = [], round(seconds * FRAME_RATE_HZ)
    for clip in clips:
        if left <= 0:
            break
        n = min(clip.n_frames, left)
        if n == clip.n_frames:  # the clip itself: its synthesis is shared
            out.append(clip)
        else:
            per_frame = clip.audio.size // max(clip.n_frames, 1)
            audio = clip.audio[: n * per_frame]
            out.append(Clip(clip.info, audio, clip.angles_rad[:n], clip.mask[:n]))
        left -= n
    return out


def verdict_note(personal: PersonalFit, part: str) -> str:
    """The enrolment's verdict on ``part`` for the table: kept the default, or how far and why."""
    verdict = personal.verdicts.get(part)
    if verdict is None:
        return "-"
    if verdict.kept_default:
        return _cell(f"kept the default: {verdict.reason}")
    return (
        f"{verdict.fit}, {verdict.strength:.0%}; expected gain {verdict.gain:+.3f} ± "
        f"{verdict.spread:.3f} ({verdict.n_folds} folds)"
    )


def holds(si: Row, sd: Row, tolerance: float = 0.005) -> bool:
    """Whether the enrolled row is at least as close as the default on every measure.

    H speed, H accel, the size ratio's distance from 1 (as the absolute log) and the
    percentiles within 25 %, each within ``tolerance`` (the table's rounding).
    """
    return (
        sd.h_speed <= si.h_speed + tolerance
        and sd.h_accel <= si.h_accel + tolerance
        and abs(np.log(sd.std_ratio)) <= abs(np.log(si.std_ratio)) + tolerance
        and sd.inside >= si.inside
    )


def evaluate_source(
    name: str,
    clips: Sequence[Clip],
    robot: RobotDescription,
    checkpoint: Checkpoint,
    synthesizers: Synthesizers,
    enroll_s: float,
    progress: Callable[[str], None] = print,
) -> tuple[list[Row], list[tuple[float, PersonalFit]]]:
    """The rows of one source and its personal fits per enrolment length (module docstring).

    The held-out speech is the same for every length: what follows the longest enrolment
    (:func:`_split`); each shorter one is its first seconds (:func:`enrolment_lengths`).
    """
    enrol_all, held = _split(clips, enroll_s)
    available = sum(c.n_frames for c in enrol_all) / FRAME_RATE_HZ
    real = [(c.angles_rad, c.mask) for c in held]
    onsets = [audio_onsets(c.audio) for c in held]
    default = synthesizers.of(checkpoint)
    si = [(synthesized_over_clip(clip, default), clip.mask) for clip in held]
    fits: list[tuple[float, PersonalFit]] = []
    for seconds in enrolment_lengths(enroll_s, available):
        enrol = first_seconds(enrol_all, seconds)
        personal = fit_personal(enrol, robot, checkpoint, synthesizers)
        progress(f"enrolled on {seconds:.0f} s: {fit_row(name, seconds, personal)}")
        fits.append((seconds, personal))
    first, second = real[0::2], real[1::2]
    if not second:  # one held-out clip: its halves
        angles, known = real[0]
        middle = angles.shape[0] // 2
        first, second = [(angles[:middle], known[:middle])], [(angles[middle:], known[middle:])]
    rows = []
    where = f"{name} ({sum(c.n_frames for c in held) / FRAME_RATE_HZ:.0f} s)"
    for part in PARTS:
        if part not in fits[-1][1].parts:
            continue
        if measure_part(real, robot, part, min_seconds=SCORE_MIN_S) is None:
            continue
        baseline = _row(where, part, "default (SI)", real, si, onsets, robot)
        rows.append(baseline)
        for seconds, personal in fits:
            enrolled = synthesizers.of(personal.checkpoint)
            sd = []
            for clip in held:
                angles = synthesized_over_clip(clip, enrolled)
                styled = style_trajectory(robot, personal.settings, angles, FRAME_RATE_HZ)
                sd.append((styled, clip.mask))
            row = _row(where, part, f"enrolled on {seconds:.0f} s (SD)", real, sd, onsets, robot)
            check = "yes" if holds(baseline, row) else "**no**"
            rows.append(replace(row, note=f"{check}; {verdict_note(personal, part)}"))
        floor_onsets = onsets[0::2] if len(real) > 1 else onsets[:1]
        rows.append(_row(where, part, "real split half", second, first, floor_onsets, robot))
        own = [(c.angles_rad, c.mask) for c in enrol_all]
        label = f"real enrolment part ({available:.0f} s)"
        rows.append(_row(where, part, label, real, own, onsets[:0], robot))
    return rows, fits


def fit_row(name: str, seconds: float, personal: PersonalFit) -> str:
    """A line of the fits table: a source's enrolment, parts learned, arms' noise and style."""
    noise = f"{personal.arms_noise:g}x" if personal.arms_noise != 1.0 else "not fitted"
    if "arms" not in personal.parts:
        noise = "- (arms not seen)"
    values = ", ".join(o.replace(":=", " ") for o in style_overrides(personal.settings))
    learned = ", ".join(personal.learned) or "none (the default kept)"
    return f"| {name} | {seconds:.0f} | {learned} | {noise} | {values or '-'} |"


FITS_HEADER = (
    "| source | enrolled on (s) | parts learned | arms' sampling noise (personal checkpoint) | "
    "style parameters against the model it runs |\n|---|---|---|---|---|"
)


def _num(value: float, digits: int = 2) -> str:
    return "-" if not np.isfinite(value) else f"{value:.{digits}f}"


def table(rows: Sequence[Row]) -> str:
    """The rows as a Markdown table."""
    lines = [
        "| source (scored) | part | motion | H speed | H accel | std ratio | "
        "percentiles within 25 % | lowest / highest ratio | beat consistency | "
        "as close as the default on every measure; the enrolment's verdict |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r.source} | {r.part} | {r.method} | {_num(r.h_speed)} | {_num(r.h_accel)} | "
            f"{_num(r.std_ratio)} | {r.inside}/{r.total} | {_num(r.lowest)} / "
            f"{_num(r.highest)} | {_num(r.beat)} | {r.note} |"
        )
    return "\n".join(lines)


def _cell(text: str) -> str:
    """Text from a data set's index as one Markdown table cell."""
    return " ".join(text.split()).replace("|", "\\|")


def sources(spec: SourceSpec, robot: RobotDescription) -> dict[str, list[Clip]]:
    """The clips of a data set by source: by :func:`source_of`, or all under ``spec.name``."""
    dataset = Dataset.open(spec.path, robot)
    by_source: dict[str, list[Clip]] = {}
    for info in dataset.clips:
        name = spec.name or source_of(info.clip_id)
        by_source.setdefault(name, []).append(dataset.load(info.clip_id))
    return by_source


def provenance_row(name: str, path: Path, clips: Sequence[Clip]) -> str:
    """A line of the sources table: data set, clips, minutes, where from, licence."""
    origins = sorted({c.info.source for c in clips})
    origin = origins[0] if len(origins) == 1 else f"{len(origins)} recordings ({origins[0]}, ...)"
    licences = "; ".join(sorted({c.info.licence for c in clips}))
    minutes = sum(c.n_frames for c in clips) / FRAME_RATE_HZ / 60.0
    return (
        f"| {name} | `{_cell(str(path))}` | {len(clips)} | {minutes:.1f} | {_cell(origin)} | "
        f"{_cell(licences)} |"
    )


PROVENANCE_HEADER = (
    "| source | data set | clips | min | from | licence |\n|---|---|---|---|---|---|"
)


def evaluate_sources(
    datasets: Sequence[SourceSpec],
    robot: RobotDescription,
    enroll_s: float,
    progress: Callable[[str], None] = print,
) -> str:
    """The SI-vs-SD table of every source (:func:`sources`), its fits, figures, origins, presets."""
    from audio2pose_ros.checkpoints.torch_io import load_checkpoint

    checkpoint = load_checkpoint(default_checkpoint_path(), robot=robot)
    synthesizers = Synthesizers()
    rows: list[Row] = []
    fits: list[str] = []
    figures: list[str] = []
    provenance: list[str] = []
    for spec in datasets:
        for name, clips in sources(spec, robot).items():
            progress(f"{name}: {len(clips)} clips")
            found, personal = evaluate_source(
                name, clips, robot, checkpoint, synthesizers, enroll_s, progress
            )
            rows += found
            fits += [fit_row(name, seconds, fit) for seconds, fit in personal]
            figures += figure_rows(name, clips, robot, synthesizers.of(checkpoint))
            provenance.append(provenance_row(name, spec.path, clips))
    return "\n\n".join(
        [
            table(rows),
            "What enrolment fitted on each source (as `audio2pose enroll` writes it: the arms' "
            "noise in the folder's `model.safetensors`, the style in its `style.yaml`):",
            "\n".join([FITS_HEADER, *fits]),
            "Each source's figures (all its clips) next to the default model's on the same "
            "speech (the presets of config/styles hold these figures):",
            "\n".join([FIGURES_HEADER, *figures]),
            "The sources: imported data sets, none of them part of the package (doc/style.md, "
            '"How well it does", gives the commands that fetch and import each):',
            "\n".join([PROVENANCE_HEADER, *provenance]),
            presets_table(robot),
        ]
    )


def presets_table(robot: RobotDescription) -> str:
    """The shipped presets and the filter's style parameters they mean for the packaged model."""
    from audio2pose_ros.style.figures import load_style, preset_names
    from audio2pose_ros.style.personal import style_settings

    lines = ["| preset | parts | style parameters against the packaged model |", "|---|---|---|"]
    for name in preset_names():
        style = load_style(name)
        settings = style_settings(default_checkpoint_path(), style, robot)
        values = ", ".join(o.replace(":=", " ") for o in style_overrides(settings))
        lines.append(f"| `{name}` | {', '.join(style.parts)} | {values} |")
    return "\n".join(lines)

"""The default head as the best single style over people: every head speaker held out in turn.

No model can guess a new speaker's style from the voice, so the default head's sampling
temperature is one style for everybody. Chosen between two recordings (GRID's calm readers and
Obama addressing a camera) on held-out clips of speakers the model learned from, it came out
slower than people who address a camera, who move their heads two to four times faster than
readers. Here it is chosen and scored on speakers the model never saw:

1. **Leave one speaker out** (:func:`speaker_fold`): for each head speaker (every GRID
   speaker and Obama), the default is built without them: ``live_groups`` trained on what the
   shipped model trains on (the talking heads and the lecture, the same early-stopping clips
   and settings) less that speaker's clips, sampled as the shipped model samples
   (:func:`with_sampling_of`). It samples the held-out speaker's speech at every head
   temperature of :data:`HEAD_TEMPERATURES` (seeds :data:`SEEDS`, the offline synthesis).
2. **Pooled over people** (:func:`pooled`): the held-out speakers' generated head motion
   against their real motion, all speakers together (each by its seconds): the Hellinger
   distances of joint speed and acceleration and the size ratio
   (:func:`~audio2pose_ros.style.crossval.part_measures`, as ``make evaluate-style`` scores a
   part); the choice's score is their mean plus ``|ln size ratio|`` (:func:`score`).
3. **The procedure scored as a whole** (:func:`nested`): for each held-out speaker, the
   temperature is chosen on the other held-out speakers' pooled figures only, and the speaker
   is scored at it; pooled over speakers, that is what a new person can expect of the choice.
4. **The shipped head** takes the temperature with the best pooled score over all speakers
   (:func:`best_temperature`).

:func:`population_figures` keeps what the regression test reads (``population.json`` beside the
model): the pooled real head motion's speed and acceleration histograms and size, the shipped
model's figures on the bundled speech (speakers no step of the build used) against them, and
the margin the test allows, the spread over held-out speakers of the nested figure.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from audio2pose_ros.checkpoints.torch_io import Checkpoint
from audio2pose_ros.data.dataset import Clip
from audio2pose_ros.learning.metrics import ACCELERATION_BINS_RAD_S2, SPEED_BINS_RAD_S, hellinger
from audio2pose_ros.robot.description import RobotDescription
from audio2pose_ros.style.crossval import Measures, part_measures
from audio2pose_ros.style.figures import Motion, _derivatives, measure_part
from audio2pose_ros.timebase import FRAME_RATE_HZ

HEAD_TEMPERATURES = (0.5, 0.75, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0)
SEEDS = (0, 1)
FIGURES_FILE = "population.json"
PART = "head"

Generated = dict[str, dict[float, list[Motion]]]  # speaker -> temperature -> motion per seed


def head_speakers(clips: Sequence[Clip], robot: RobotDescription) -> dict[str, list[Clip]]:
    """The clips that observe the head, by speaker (sorted)."""
    head = robot.group_mask(PART)
    out: dict[str, list[Clip]] = {}
    for clip in sorted(clips, key=lambda c: c.info.clip_id):
        if clip.mask[:, head].any():
            out.setdefault(clip.info.speaker, []).append(clip)
    return dict(sorted(out.items()))


def speaker_fold(
    clips: Sequence[Clip], stopping: set[str], speaker: str
) -> tuple[tuple[Clip, ...], tuple[Clip, ...]]:
    """(training, early-stopping clips) of the default built without ``speaker``.

    The build's own split (:func:`~audio2pose_ros.learning.source_holdout.split_training`:
    ``stopping`` are the build's early-stopping clips) less every clip of ``speaker``.
    """
    from audio2pose_ros.learning.source_holdout import split_training

    return split_training(clips, stopping, lambda info: info.speaker == speaker)


def with_sampling_of(fold: Checkpoint, shipped: Checkpoint) -> Checkpoint:
    """``fold``'s weights sampled as ``shipped`` samples (every sampling setting copied).

    A fold's training leaves the configured sampling settings; the shipped model's were chosen
    by the build (:mod:`~audio2pose_ros.learning.sampler_selection`: the head's per-joint
    burstiness and noise correlation, the sampler's velocity bound, the rest level in silence).
    Scoring a fold with other settings scores another sampler than the one that ships (folds
    trained on the talking heads alone moved their held-out heads 2.75 times people's size at
    temperature 1 with the configured settings, 1.54 times with the shipped ones).
    """
    from audio2pose_ros.models.live_groups import SAMPLING_SETTINGS

    config = shipped.model.config
    settings = {k: getattr(config, k) for k in SAMPLING_SETTINGS}
    model = fold.model.with_sampling(**settings)  # type: ignore[operator]
    return replace(fold, model=model)


def with_head_temperature(checkpoint: Checkpoint, temperature: float) -> Checkpoint:
    """``checkpoint`` whose head part samples at ``temperature`` (same weights)."""
    model = checkpoint.model.with_sampling(first_temperature=temperature)  # type: ignore[operator]
    return replace(checkpoint, model=model)


def sample_heads(
    checkpoint: Checkpoint, clips: Sequence[Clip], temperatures: Sequence[float] = HEAD_TEMPERATURES
) -> dict[float, list[Motion]]:
    """Temperature -> the model's offline synthesis of each clip per seed, as long as the clip.

    Each motion carries its clip's mask (a seed's motions follow the clips in order).
    """
    from audio2pose_ros.offline.synthesis import synthesize

    out: dict[float, list[Motion]] = {}
    for temperature in temperatures:
        model = with_head_temperature(checkpoint, temperature)
        motions = []
        for seed in SEEDS:
            for clip in clips:
                angles = synthesize(model, clip.audio, seed=seed, body_margin_m=None)[1]
                n = min(len(angles), clip.n_frames)
                pad = np.repeat(angles[n - 1 : n], clip.n_frames - n, axis=0)
                motions.append((np.vstack([angles[:n], pad]), clip.mask))
        out[temperature] = motions
    return out


def real_of(clips: Sequence[Clip]) -> list[Motion]:
    """The clips' real motion, once per seed (aligned with :func:`sample_heads`)."""
    return [(c.angles_rad, c.mask) for _ in SEEDS for c in clips]


def score(measures: Measures) -> float:
    """The choice's score: mean of the two Hellinger distances plus ``|ln size ratio|``."""
    return 0.5 * (measures.h_speed + measures.h_accel) + measures.log_size


def pooled(
    real: Mapping[str, list[Motion]],
    generated: Mapping[str, list[Motion]],
    robot: RobotDescription,
    speakers: Sequence[str] | None = None,
) -> Measures:
    """The head's measures of ``speakers``' generated motion against their real motion, pooled."""
    chosen = list(real) if speakers is None else list(speakers)
    return part_measures(
        [m for s in chosen for m in real[s]], [m for s in chosen for m in generated[s]], robot, PART
    )


def best_temperature(
    real: Mapping[str, list[Motion]],
    generated: Generated,
    robot: RobotDescription,
    speakers: Sequence[str],
) -> float:
    """The temperature of the best pooled :func:`score` over ``speakers`` (the lower on a tie)."""
    temperatures = sorted(next(iter(generated.values())))

    def of(t: float) -> float:
        return score(pooled(real, {s: generated[s][t] for s in speakers}, robot, speakers))

    return min(temperatures, key=of)


@dataclass(frozen=True)
class NestedResult:
    """The choice scored as a whole (:func:`nested`).

    Attributes:
        chosen: held-out speaker -> the temperature chosen without them.
        measures: pooled over speakers, each at the temperature chosen without them.
        per_speaker: each speaker's own measures at that temperature.
        motion: each speaker's generated motion at that temperature.
    """

    chosen: dict[str, float]
    measures: Measures
    per_speaker: dict[str, Measures]
    motion: dict[str, list[Motion]]

    def size_ratio(self, real: Mapping[str, list[Motion]], robot: RobotDescription) -> float:
        """The pooled size ratio, generated / real, over every held-out speaker."""
        return signed_ratio(
            [m for s in real for m in real[s]], [m for s in real for m in self.motion[s]], robot
        )

    def spread(self) -> tuple[float, float]:
        """The standard error over speakers of H speed and H accel (the test's margin)."""
        n = len(self.per_speaker)
        speed = [m.h_speed for m in self.per_speaker.values()]
        accel = [m.h_accel for m in self.per_speaker.values()]
        return (
            float(np.std(speed, ddof=1) / math.sqrt(n)),
            float(np.std(accel, ddof=1) / math.sqrt(n)),
        )


def nested(
    real: Mapping[str, list[Motion]], generated: Generated, robot: RobotDescription
) -> NestedResult:
    """Each speaker scored at the temperature chosen on the other held-out speakers."""
    chosen = {
        s: best_temperature(real, generated, robot, [o for o in real if o != s]) for s in real
    }
    motion = {s: generated[s][t] for s, t in chosen.items()}
    per_speaker = {s: pooled(real, motion, robot, [s]) for s in real}
    return NestedResult(chosen, pooled(real, motion, robot), per_speaker, motion)


def _row(label: str, m: Measures, ratio: float) -> str:
    return f"| {label} | {m.h_speed:.3f} | {m.h_accel:.3f} | {ratio:.2f} | {score(m):.3f} |"


def signed_ratio(real: Sequence[Motion], model: Sequence[Motion], robot: RobotDescription) -> float:
    """The head's size ratio, model / real (not folded into a distance)."""
    sizes = [measure_part(m, robot, PART, min_seconds=0.0) for m in (real, model)]
    if sizes[0] is None or sizes[1] is None:
        return math.nan
    return sizes[1].std_rad / sizes[0].std_rad


def population_table(
    real: Mapping[str, list[Motion]],
    generated: Generated,
    robot: RobotDescription,
    source_of: Callable[[str], str],
    result: NestedResult,
) -> str:
    """The card's table: per temperature, pooled and per source; then the nested choice."""
    sources = sorted({source_of(s) for s in real})
    lines = [
        "| head temperature | held-out speakers | H speed | H accel | size ratio | score |",
        "|---|---|---|---|---|---|",
    ]
    for t in sorted(next(iter(generated.values()))):
        motion = {s: generated[s][t] for s in real}
        groups = [("all", list(real))] + [
            (source, [s for s in real if source_of(s) == source]) for source in sources
        ]
        for label, speakers in groups:
            m = pooled(real, motion, robot, speakers)
            ratio = signed_ratio(
                [x for s in speakers for x in real[s]],
                [x for s in speakers for x in motion[s]],
                robot,
            )
            lines.append(
                f"| {t:g} | {label} ({len(speakers)}) | {m.h_speed:.3f} | {m.h_accel:.3f} | "
                f"{ratio:.2f} | {score(m):.3f} |"
            )
    chosen = ", ".join(f"{s} {t:g}" for s, t in result.chosen.items())
    speed, accel = result.spread()
    lines += [
        "",
        "Each speaker at the temperature chosen on the other held-out speakers only "
        f"({chosen}); the spread is the standard error over the {len(real)} speakers:",
        "",
        "| held out | H speed | H accel | size ratio | score |",
        "|---|---|---|---|---|",
        *[
            _row(s, m, signed_ratio(real[s], result.motion[s], robot))
            for s, m in result.per_speaker.items()
        ],
        _row(
            f"**all, pooled** (± {speed:.3f} / {accel:.3f})",
            result.measures,
            result.size_ratio(real, robot),
        ),
    ]
    return "\n".join(lines)


def histograms(motions: Sequence[Motion], robot: RobotDescription) -> tuple[np.ndarray, ...]:
    """The head's pooled speed and acceleration counts on the bins of the measures."""
    joints = [int(j) for j in np.flatnonzero(robot.group_mask(PART))]
    out = []
    for order, bins in ((1, SPEED_BINS_RAD_S), (2, ACCELERATION_BINS_RAD_S2)):
        values = np.concatenate([_derivatives(motions, j, order, FRAME_RATE_HZ) for j in joints])
        out.append(np.histogram(values, bins)[0])
    return tuple(out)


def against_reference(
    motions: Sequence[Motion], figures: Mapping[str, object], robot: RobotDescription
) -> tuple[float, float, float]:
    """H speed, H accel and size ratio of ``motions``' head against recorded real figures."""
    speed, accel = histograms(motions, robot)
    size = measure_part(motions, robot, PART, min_seconds=0.0)
    assert size is not None
    reference = figures["reference"]
    assert isinstance(reference, dict)
    return (
        hellinger(np.asarray(reference["speed_counts"]), speed),
        hellinger(np.asarray(reference["accel_counts"]), accel),
        size.std_rad / float(reference["std_rad"]),
    )


def bundled_motions(checkpoint: Checkpoint, seeds: Sequence[int]) -> list[Motion]:
    """The model's offline synthesis of the bundled speech (other speakers), every frame known."""
    from audio2pose_ros.audio.wav import read_wav
    from audio2pose_ros.offline.synthesis import synthesize
    from audio2pose_ros.resources import bundled_speech_paths

    out = []
    for wav in bundled_speech_paths():
        audio = read_wav(wav)[0]
        for seed in seeds:
            angles = synthesize(checkpoint, audio, seed=seed, body_margin_m=None)[1]
            out.append((angles, np.ones(angles.shape, dtype=bool)))
    return out


def population_figures(
    real: Mapping[str, list[Motion]],
    result: NestedResult,
    shipped: Checkpoint,
    temperature: float,
) -> dict[str, object]:
    """What ``population.json`` keeps (module docstring)."""
    robot = shipped.robot
    everyone = [m for s in real for m in real[s][: len(real[s]) // len(SEEDS)]]
    speed, accel = histograms(everyone, robot)
    size = measure_part(everyone, robot, PART, min_seconds=0.0)
    assert size is not None
    figures: dict[str, object] = {
        "head_temperature": temperature,
        "reference": {
            "speakers": list(real),
            "speed_counts": speed.tolist(),
            "accel_counts": accel.tolist(),
            "std_rad": size.std_rad,
        },
        "held_out_speakers": {
            "h_speed": result.measures.h_speed,
            "h_accel": result.measures.h_accel,
            "size_ratio": result.size_ratio(real, robot),
            "chosen": result.chosen,
        },
    }
    seeds = list(SEEDS)
    h_speed, h_accel, ratio = against_reference(bundled_motions(shipped, seeds), figures, robot)
    margin = max(result.spread())
    figures["bundled_speech"] = {
        "seeds": seeds,
        "h_speed": h_speed,
        "h_accel": h_accel,
        "size_ratio": ratio,
        "margin": margin,
    }
    return figures


def write_figures(path: Path, figures: Mapping[str, object]) -> Path:
    """Write ``population.json``."""
    path.write_text(json.dumps(figures, indent=1) + "\n", encoding="utf-8")
    return path


def run(
    talking_heads: Path,
    work_dir: Path,
    model_dir: Path,
    robot: RobotDescription,
    progress: Callable[[str], None] = print,
    lecture_video: Path | None = None,
    retrain: bool = True,
) -> str:
    """Hold out every head speaker, choose the shipped head's temperature, keep the figures.

    With ``retrain``, each held-out speaker gets the default built without them: ``live_groups``
    trained as ``make default-model`` trains the shipped model (the same talking heads and
    lecture stretches, the same early-stopping clips and training settings,
    :func:`~audio2pose_ros.learning.source_holdout.split_training`), less that speaker's clips,
    and sampled with the shipped model's sampling settings (:func:`with_sampling_of`; the
    choice of those settings is not repeated per fold). The talking heads and the lecture
    (``lecture_video``, needed then) are imported into ``work_dir`` unless they are there; each
    fold's model is kept there (``loso_<speaker>.safetensors``) and reused. Without
    ``retrain`` every fold samples with the shipped weights (which learned from every speaker:
    only the temperature's choice then holds the speaker out; quick). The shipped checkpoint of
    ``model_dir`` gets the chosen head temperature; ``population.json`` is written beside it.

    Returns:
        The card's table.

    Raises:
        ValueError: ``retrain`` without ``lecture_video``.

    """
    from audio2pose_ros.checkpoints.torch_io import load_checkpoint, save_checkpoint
    from audio2pose_ros.data.dataset import Dataset
    from audio2pose_ros.learning.default_model import (
        LearnedBuildSettings,
        import_both,
        import_talking_heads,
        validation_ids,
    )
    from audio2pose_ros.learning.model_card import WHAT_BEGIN, WHAT_END, what_it_is
    from audio2pose_ros.learning.source_holdout import MODEL_NAME, speaker_source
    from audio2pose_ros.learning.style_card import put_section
    from audio2pose_ros.learning.training import train_on_clips

    if retrain and lecture_video is None:
        raise ValueError("retraining the held-out speakers' models needs the lecture video")
    heads_dir, lecture_dir = work_dir / "talking_heads", work_dir / "lecture"
    imported = (heads_dir / "index.json").is_file() and (
        not retrain or (lecture_dir / "index.json").is_file()
    )
    if not imported and lecture_video is not None:
        import_both(talking_heads, lecture_video, work_dir, robot, 1, progress)
    elif not imported:
        import_talking_heads(talking_heads, heads_dir, robot, progress)
    heads = Dataset.open(heads_dir, robot)
    head_clips = [heads.load(c.clip_id) for c in heads.clips]
    by_speaker = head_speakers(head_clips, robot)
    every = list(head_clips)
    if retrain:
        lecture = Dataset.open(lecture_dir, robot)
        every += [lecture.load(c.clip_id) for c in lecture.clips]
    stopping = validation_ids([c for c in every if c.info.split == "train"])
    build = LearnedBuildSettings()
    settings = build.train_settings(build.max_epochs)
    real: dict[str, list[Motion]] = {}
    generated: Generated = {}
    shipped_path = model_dir / "default.safetensors"
    shipped = load_checkpoint(shipped_path, robot=robot)
    for speaker in by_speaker:
        path = work_dir / f"loso_{speaker}.safetensors"
        if not retrain:
            model = shipped
        else:
            if path.is_file():
                model = load_checkpoint(path, robot=robot)
            else:
                training, validation = speaker_fold(every, stopping, speaker)
                progress(
                    f"training without {speaker} on {len(training)} clips, early stopping on "
                    f"{sorted(c.info.clip_id for c in validation)}"
                )
                model, _ = train_on_clips(MODEL_NAME, training, robot, settings, None, validation)
                save_checkpoint(path, model)
            model = with_sampling_of(model, shipped)
        progress(f"sampling {speaker} at head temperatures {HEAD_TEMPERATURES}")
        generated[speaker] = sample_heads(model, by_speaker[speaker])
        real[speaker] = real_of(by_speaker[speaker])
    result = nested(real, generated, robot)
    temperature = best_temperature(real, generated, robot, list(real))
    progress(f"the head temperature over everyone: {temperature:g}")
    shipped = with_head_temperature(shipped, temperature)
    chosen_on = f"every head speaker held out in turn: {', '.join(real)} ({FIGURES_FILE})"
    shipped = replace(shipped, info={**shipped.info, "head_temperature_chosen_on": chosen_on})
    save_checkpoint(shipped_path, shipped)
    figures = population_figures(real, result, shipped, temperature)
    write_figures(model_dir / FIGURES_FILE, figures)

    def source_of(speaker: str) -> str:
        return speaker_source(speaker) or speaker

    table = population_table(real, generated, robot, source_of, result)
    write_card(model_dir / "MODEL_CARD.md", table, figures, temperature, retrain)
    put_section(model_dir / "MODEL_CARD.md", WHAT_BEGIN, WHAT_END, [what_it_is(shipped)])
    return table


COMMAND = (
    "python -m audio2pose_ros.style.population {how} "
    "../shared/data/talking_heads out/default-model-work models/default"
)


def write_card(
    card: Path, table: str, figures: Mapping[str, object], temperature: float, retrain: bool
) -> None:
    """The card's population section: the table, the shipped choice and the test's figures."""
    from audio2pose_ros.learning.style_card import POPULATION_BEGIN, POPULATION_END, put_section

    held = figures["held_out_speakers"]
    bundled = figures["bundled_speech"]
    assert isinstance(held, dict)
    assert isinstance(bundled, dict)
    how = "--lecture ../shared/data/lecture_video/physicsworks.webm"
    command = COMMAND.format(how=how if retrain else "--shipped-weights")
    put_section(
        card,
        POPULATION_BEGIN,
        POPULATION_END,
        [
            "## The head over people: every head speaker held out",
            "",
            "No model can guess a new speaker's style from the voice, so the head's sampling "
            "temperature is one style for everybody, chosen here on speakers the model never "
            "saw (`audio2pose_ros/style/population.py`): for each head speaker (each GRID "
            "speaker, Obama), "
            + (
                "the default built without them (`live_groups` trained as the shipped model is, "
                "on the same talking heads and lecture stretches with the same early stopping, "
                "less that speaker's clips, and sampled with the shipped model's sampling "
                "settings; the choice of those settings is not repeated per speaker) "
                if retrain
                else "the shipped `live_groups` (its weights learned from every speaker: here "
                "only the temperature's choice holds the speaker out) "
            )
            + "samples the held-out speaker's speech at head temperatures "
            f"{', '.join(map(str, HEAD_TEMPERATURES))} "
            f"(seeds {', '.join(map(str, SEEDS))}); its head against the speaker's real head, "
            "all speakers pooled (each by its seconds), as `make evaluate-style` scores a part: "
            "the Hellinger distances of joint speed and acceleration, the size ratio, and the "
            "choice's score, their mean plus |ln size ratio|. The arms have one source, the "
            "lecture (one speaker): no speaker can be held out, they are scored on its held-out "
            "stretch above.",
            "",
            table,
            "",
            f"**The shipped head samples at temperature {temperature:g}**, the best pooled "
            "score over all speakers (this step sets it in `default.safetensors` after the "
            "build's own choice above). On speakers held out, the choice as a whole gives head "
            f"H speed / H accel {held['h_speed']:.3f} / {held['h_accel']:.3f} with size ratio "
            f"{held['size_ratio']:.2f} (goal: <= 0.15 each, size 0.7 to 1.4). Pooled, the "
            "speakers' motion is one distribution; one speaker at a time, no single head is "
            "close to both kinds of speaker: the readers move less than it, the one speaker "
            "addressing a camera more (the per-speaker rows).",
            "",
            "`population.json` keeps the people's pooled head histograms and size, and the "
            "shipped model's figures on the bundled speech (speakers no step used) against them: "
            f"H {bundled['h_speed']:.3f} / {bundled['h_accel']:.3f}, size ratio "
            f"{bundled['size_ratio']:.2f}. `test/test_population.py` (in `make test`) fails "
            "when the packaged model's head moves further from people than that by more than "
            f"{bundled['margin']:.3f}, the standard error over the held-out speakers of their "
            "H.",
            "",
            f"Rebuild: `{command}` (run by `make default-model`).",
        ],
    )


def main(argv: Sequence[str] | None = None) -> int:
    """The command line: ``--lecture VIDEO`` (or ``--shipped-weights``) ``HEADS WORK MODEL_DIR``."""
    import argparse

    from audio2pose_ros.robot.description import load_robot

    parser = argparse.ArgumentParser(
        prog="python -m audio2pose_ros.style.population",
        description="the default head's temperature chosen over people, every head speaker "
        "held out",
    )
    how = parser.add_mutually_exclusive_group(required=True)
    how.add_argument(
        "--lecture", type=Path, help="the lecture video: train the default without each speaker"
    )
    how.add_argument(
        "--shipped-weights",
        action="store_true",
        help="sample every speaker with the shipped weights (quick; they saw every speaker)",
    )
    parser.add_argument("heads", type=Path, help="the talking-head clips")
    parser.add_argument("work", type=Path, help="imports and the held-out models go here")
    parser.add_argument("model_dir", type=Path, help="holds default.safetensors")
    args = parser.parse_args(argv)
    table = run(
        args.heads,
        args.work,
        args.model_dir,
        load_robot(),
        lecture_video=args.lecture,
        retrain=not args.shipped_weights,
    )
    print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

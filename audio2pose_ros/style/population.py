"""The default head as the best single style over people: every head speaker held out in turn.

No model can guess a new speaker's style from the voice, so the default head's sampling
temperature is one style for everybody. Chosen between two recordings (GRID's calm readers and
Obama addressing a camera) on held-out clips of speakers the model learned from, it came out
slower than people who address a camera, who move their heads two to four times faster than
readers. Here it is chosen and scored on speakers the model never saw:

1. **Leave one speaker out** (:func:`head_folds`): for each head speaker (every GRID speaker
   and Obama), ``live_groups`` is trained on the other speakers' talking-head clips only (the
   head part learns from them alone; early stopping on one clip of another speaker) and
   samples the held-out speaker's speech at every head temperature of
   :data:`HEAD_TEMPERATURES` (seeds :data:`SEEDS`, the offline synthesis).
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

HEAD_TEMPERATURES = (1.0, 1.5, 2.0, 2.5, 3.0, 4.0)
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


def head_folds(
    by_speaker: Mapping[str, Sequence[Clip]],
) -> list[tuple[str, list[Clip], list[Clip]]]:
    """(held-out speaker, training clips, early-stopping clips) per head speaker.

    The early-stopping clip is the first clip of the next speaker in order (another speaker
    than the held-out one, out of the training clips).
    """
    speakers = list(by_speaker)
    folds = []
    for i, speaker in enumerate(speakers):
        other = speakers[(i + 1) % len(speakers)]
        validation = [by_speaker[other][0]]
        training = [
            c for s in speakers if s != speaker for c in by_speaker[s] if c is not validation[0]
        ]
        folds.append((speaker, training, validation))
    return folds


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
    max_epochs: int = 200,
    retrain: bool = True,
) -> str:
    """Hold out every head speaker, choose the shipped head's temperature, keep the figures.

    The talking heads are imported into ``work_dir`` unless they are there; each fold's model
    is kept there (``loso_<speaker>.safetensors``) and reused. Without ``retrain`` every fold
    samples with the shipped weights (which learned from every speaker: only the temperature's
    choice then holds the speaker out; quick, for a machine without the hours of training).
    The shipped checkpoint of ``model_dir`` gets the chosen head temperature;
    ``population.json`` is written beside it.

    Returns:
        The card's table.
    """
    from audio2pose_ros.checkpoints.torch_io import load_checkpoint, save_checkpoint
    from audio2pose_ros.data.dataset import Dataset
    from audio2pose_ros.learning.default_model import LearnedBuildSettings, import_talking_heads
    from audio2pose_ros.learning.model_card import WHAT_BEGIN, WHAT_END, what_it_is
    from audio2pose_ros.learning.source_holdout import MODEL_NAME, speaker_source
    from audio2pose_ros.learning.style_card import put_section
    from audio2pose_ros.learning.training import train_on_clips

    data = work_dir / "talking_heads"
    if not (data / "index.json").is_file():
        import_talking_heads(talking_heads, data, robot, progress)
    dataset = Dataset.open(data, robot)
    by_speaker = head_speakers([dataset.load(c.clip_id) for c in dataset.clips], robot)
    settings = LearnedBuildSettings().train_settings(max_epochs)
    real: dict[str, list[Motion]] = {}
    generated: Generated = {}
    shipped_path = model_dir / "default.safetensors"
    for speaker, training, validation in head_folds(by_speaker):
        path = work_dir / f"loso_{speaker}.safetensors"
        if not retrain:
            model = load_checkpoint(shipped_path, robot=robot)
        elif path.is_file():
            model = load_checkpoint(path, robot=robot)
        else:
            progress(f"training without {speaker} on {len(training)} clips")
            model, _ = train_on_clips(MODEL_NAME, training, robot, settings, None, validation)
            save_checkpoint(path, model)
        progress(f"sampling {speaker} at head temperatures {HEAD_TEMPERATURES}")
        generated[speaker] = sample_heads(model, by_speaker[speaker])
        real[speaker] = real_of(by_speaker[speaker])
    result = nested(real, generated, robot)
    temperature = best_temperature(real, generated, robot, list(real))
    progress(f"the head temperature over everyone: {temperature:g}")
    shipped = load_checkpoint(shipped_path, robot=robot)
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
    "python -m audio2pose_ros.style.population [--shipped-weights] "
    "../shared/data/talking_heads out/style-sources models/default"
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
    command = COMMAND.replace("[--shipped-weights] ", "" if retrain else "--shipped-weights ")
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
                "`live_groups` trained on the other speakers' clips "
                if retrain
                else "the shipped `live_groups` (its weights learned from every speaker: here "
                "only the temperature's choice holds the speaker out; a training per speaker "
                "did not fit this machine's budget) "
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
            f"{held['size_ratio']:.2f} (goal: <= 0.15 each, size 0.7 to 1.4).",
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
    """``python -m audio2pose_ros.style.population [--shipped-weights] HEADS WORK MODEL_DIR``."""
    import sys

    from audio2pose_ros.robot.description import load_robot

    args = list(sys.argv[1:] if argv is None else argv)
    retrain = "--shipped-weights" not in args
    args = [a for a in args if a != "--shipped-weights"]
    if len(args) != 3:
        print(main.__doc__, file=sys.stderr)
        return 2
    table = run(Path(args[0]), Path(args[1]), Path(args[2]), load_robot(), retrain=retrain)
    print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""A style as measured figures of a person's motion, and how they resolve into filter settings.

A style file (a preset under ``config/styles/``, or ``style.yaml`` of a personal model written by
``audio2pose enroll``) holds, per observed part (head, arms, hip), figures measured from real
motion at 100 Hz (:func:`measure`):

- ``std_rad``: the part's size, the RMS over its joints of each joint's angle std;
- ``speed_deciles_rad_s``, ``accel_deciles_rad_s2``: the deciles (p10 to p90) of joint speed
  and acceleration pooled over the part's joints (seed 003 section 5.3 compares the same
  derivative distributions by the Hellinger distance);
- arms only: ``rest_pitch_rad`` (median shoulder pitch: where the hands rest), ``rest_bend_rad``
  (median elbow bend) and ``raise_p1_rad`` (1st percentile of the shoulder pitch: how high the
  arms go).

A part observed for less than :data:`MIN_PART_S` is left out, and a part left out keeps the
model's own motion. The figures are absolute, so a style means the same after a model is rebuilt:
:func:`resolve` turns them into :class:`~audio2pose_ros.motion.style.StyleSettings` against the
model's own motion on reference speech (the enrolment recording's speech when there is one, else
the bundled speech: :func:`~audio2pose_ros.style.personal.model_reference`): the tempo and size
whose styled model motion has the upper deciles (:data:`FIT_DECILES`, p50 to p90) and std
closest to the person's (as log ratios); the arm rest offsets move the styled model's rest onto
the person's, and the height limit is the person's ``raise_p1_rad``.

Why the upper deciles only: a linear, causal transform cannot make continuous motion
intermittent (a person at rest between fast gestures), so it cannot match a person's low and
high deciles at once. The held-out evaluation scores p50, p90 and p99 and the Hellinger
distance on 0.1 rad/s and 5 rad/s² bins, where the low deciles of such a person (near zero)
share one or two bins. Fitted to every decile, the style slowed the whole motion down to the
person's stillness: on the lecture's enrolment stretch (its first 32 s, scored against itself
as the evaluation scores held-out motion) tempo 0.5 and acceleration H 0.22, worse than the
unstyled model's 0.16, with 6 of 48 percentiles within 25 %; fitted to p50 to p90, tempo 0.6,
H 0.17 and 11 of 48.
"""

from __future__ import annotations

import itertools
import math
import re
from collections.abc import Collection, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import yaml

from audio2pose_ros.errors import ConfigurationError, InputError, short_repr
from audio2pose_ros.files import read_yaml_file
from audio2pose_ros.motion.style import (
    IDENTITY,
    MAX_GAIN,
    MAX_REST_OFFSET_RAD,
    MAX_TEMPO,
    MIN_TEMPO,
    STYLE_FIELDS,
    StyleSettings,
    StyleTransform,
)
from audio2pose_ros.resources import share_path
from audio2pose_ros.robot.description import JOINT_GROUPS, RobotDescription
from audio2pose_ros.timebase import FRAME_RATE_HZ

Motion = tuple[np.ndarray, np.ndarray]  # (T, J) angles in radians, (T, J) known mask
STYLE_FORMAT = 1
MIN_PART_S = 5.0  # a part observed for less than this is not measured (not adapted)
TEMPO_GRID = (MIN_TEMPO, 0.3, 0.4, 0.5, 0.6, 0.7, 0.85, 1.0, 1.2, 1.4, 1.7, 2.0, 2.4, MAX_TEMPO)
GAIN_GRID = np.geomspace(0.02, MAX_GAIN, 141)  # sizes tried per tempo (about 3.3 % apart)
DECILES = tuple(range(10, 100, 10))
FIT_DECILES = (50, 60, 70, 80, 90)  # the deciles resolve() matches (module docstring)
MAX_STYLE_BYTES = 65536
# plausible bounds of the figures in a style file (hostile or broken files are refused)
_BOUNDS = {
    "seconds": (0.0, 1e6),
    "std_rad": (1e-4, 2.0),
    "speed_deciles_rad_s": (1e-6, 40.0),
    "accel_deciles_rad_s2": (1e-5, 5000.0),
    "rest_pitch_rad": (-2.1, 2.1),
    "rest_bend_rad": (-0.1, 1.6),
    "raise_p1_rad": (-2.1, 2.1),
}
_ARM_FIELDS = ("rest_pitch_rad", "rest_bend_rad", "raise_p1_rad")
_LIST_FIELDS = ("speed_deciles_rad_s", "accel_deciles_rad_s2")


def _rounded(value: float) -> float:
    """A figure as kept (6 significant digits): what is written is what was measured."""
    return float(f"{float(value):.6g}")


class StyleError(InputError):
    """A style file, preset name or figure is refused (the message says which and why)."""


@dataclass(frozen=True)
class PartFigures:
    """Measured figures of one part (see the module docstring); arm fields are None elsewhere."""

    seconds: float
    std_rad: float
    speed_deciles_rad_s: tuple[float, ...]
    accel_deciles_rad_s2: tuple[float, ...]
    rest_pitch_rad: float | None = None
    rest_bend_rad: float | None = None
    raise_p1_rad: float | None = None

    def __post_init__(self) -> None:
        """Refuse figures outside their plausible range (a style file is untrusted input).

        Raises:
            StyleError: a figure is not a finite number inside its bounds.
        """
        for name, (low, high) in _BOUNDS.items():
            value = getattr(self, name)
            if value is None and name in _ARM_FIELDS:
                continue
            many = name in _LIST_FIELDS
            if many and not (isinstance(value, list | tuple) and len(value) == len(DECILES)):
                raise StyleError(f"style figure {name}: needs {len(DECILES)} numbers (p10..p90)")
            for item in value if many else (value,):
                if (
                    isinstance(item, bool)
                    or not isinstance(item, int | float)
                    or not math.isfinite(item)
                    or not low <= item <= high
                ):
                    raise StyleError(
                        f"style figure {name}: {short_repr(item, 40)} is not a number in "
                        f"[{low:g}, {high:g}]"
                    )
            if many:
                if any(b < a for a, b in itertools.pairwise(value)):
                    raise StyleError(f"style figure {name}: deciles must not decrease")
                object.__setattr__(self, name, tuple(_rounded(v) for v in value))
            elif value is not None:
                object.__setattr__(self, name, _rounded(value))

    @property
    def speed_p50_rad_s(self) -> float:
        """Median joint speed (rad/s)."""
        return self.speed_deciles_rad_s[DECILES.index(50)]

    def as_dict(self) -> dict[str, object]:
        """The figures to write (arm fields only where set)."""
        out: dict[str, object] = {}
        for key, value in asdict(self).items():
            if isinstance(value, tuple | list):
                out[key] = list(value)
            elif value is not None:
                out[key] = value
        return out


@dataclass(frozen=True)
class StyleFile:
    """A named style: its figures per part, and where they come from.

    Attributes:
        name: short name (a preset's file stem, or the enrolled person's folder name).
        description: one line for people.
        source: the recording(s) measured, with their licence or attribution.
        command: the command that re-measures the figures.
        parts: part -> figures; parts not present are not adapted.
        fitted: (SHA-256 of a checkpoint, the settings for it), or None; used instead of
            resolving the figures when that checkpoint runs. Enrolment fits them on the
            person's own speech; a preset keeps them resolved against the packaged model
            (``python -m audio2pose_ros.style.presets --resolve``), so a start needs no
            synthesis.
    """

    name: str
    description: str
    source: str
    command: str
    parts: Mapping[str, PartFigures]
    fitted: tuple[str, StyleSettings] | None = None

    def to_yaml(self) -> str:
        """The file's text."""
        document = {
            "audio2pose_style": STYLE_FORMAT,
            "name": self.name,
            "description": self.description,
            "source": self.source,
            "command": self.command,
            "parts": {part: figures.as_dict() for part, figures in self.parts.items()},
        }
        if self.fitted is not None:
            document["fitted"] = {
                "checkpoint_sha256": self.fitted[0],
                "settings": {
                    name: getattr(self.fitted[1], name)
                    for name in STYLE_FIELDS
                    if getattr(self.fitted[1], name) != getattr(IDENTITY, name)
                },
            }
        return yaml.safe_dump(document, sort_keys=False, width=100, default_flow_style=None)

    def write(self, path: Path) -> Path:
        """Write the file (its folder must exist)."""
        path.write_text(self.to_yaml(), encoding="utf-8")
        return path


def _text(document: Mapping[str, object], key: str, path: Path) -> str:
    value = document.get(key, "")
    if not isinstance(value, str) or len(value) > 2000:
        raise StyleError(f"{path}: {key} must be a text of at most 2000 characters")
    return value


def read_style(path: str | Path) -> StyleFile:
    """Read and check a style file.

    Raises:
        StyleError: missing, oversized or unparsable file, unknown format, part or figure, or a
            figure outside its plausible range.
    """
    file = Path(path)
    document = read_yaml_file(file, "style", StyleError, MAX_STYLE_BYTES)
    if not isinstance(document, dict) or document.get("audio2pose_style") != STYLE_FORMAT:
        raise StyleError(f"{file}: not a style file (needs 'audio2pose_style: {STYLE_FORMAT}')")
    parts_raw = document.get("parts")
    if not isinstance(parts_raw, dict):
        raise StyleError(f"{file}: 'parts' must map parts ({', '.join(JOINT_GROUPS)}) to figures")
    parts: dict[str, PartFigures] = {}
    for part, figures in parts_raw.items():
        if part not in JOINT_GROUPS:
            raise StyleError(f"{file}: unknown part {short_repr(part, 40)}; known: {JOINT_GROUPS}")
        if not isinstance(figures, dict):
            raise StyleError(f"{file}: the figures of {part} must be a mapping")
        wanted = set(_BOUNDS) - (set() if part == "arms" else set(_ARM_FIELDS))
        required = wanted - (set(_ARM_FIELDS) if part == "arms" else set())
        unknown, missing = set(figures) - wanted, required - set(figures)
        if unknown or missing:
            raise StyleError(
                f"{file}: figures of {part}: unknown {sorted(map(str, unknown))}, "
                f"missing {sorted(missing)}"
            )
        try:
            parts[part] = PartFigures(**figures)
        except StyleError as exc:
            raise StyleError(f"{file}: {part}: {exc}") from None
    return StyleFile(
        name=_text(document, "name", file),
        description=_text(document, "description", file),
        source=_text(document, "source", file),
        command=_text(document, "command", file),
        parts=parts,
        fitted=_fitted(document.get("fitted"), file),
    )


def _fitted(raw: object, file: Path) -> tuple[str, StyleSettings] | None:
    """The ``fitted`` entry of a style file, checked (the settings by their declarations)."""
    if raw is None:
        return None
    if not isinstance(raw, dict) or set(raw) != {"checkpoint_sha256", "settings"}:
        raise StyleError(f"{file}: 'fitted' needs checkpoint_sha256 and settings only")
    digest, settings = raw["checkpoint_sha256"], raw["settings"]
    if not isinstance(digest, str) or not re.fullmatch(r"[0-9a-f]{64}", digest):
        raise StyleError(f"{file}: fitted checkpoint_sha256 must be 64 hex digits")
    if not isinstance(settings, dict) or not set(settings) <= set(STYLE_FIELDS):
        raise StyleError(f"{file}: fitted settings must map style parameters {STYLE_FIELDS}")
    try:
        return digest, StyleSettings(**settings)
    except ConfigurationError as exc:
        raise StyleError(f"{file}: fitted {exc}") from None


def presets_dir() -> Path:
    """Where the named presets live (``config/styles``)."""
    return share_path("config", "styles")


def preset_names() -> list[str]:
    """The names of the shipped presets."""
    return sorted(p.stem for p in presets_dir().glob("*.yaml"))


def load_style(name_or_path: str) -> StyleFile:
    """A style by preset name, style file, or personal model folder (its ``style.yaml``).

    Raises:
        StyleError: neither a preset nor a readable style file.
    """
    path = Path(name_or_path)
    if path.is_dir():
        return read_style(path / "style.yaml")
    if path.suffix in (".yaml", ".yml") or path.exists():
        return read_style(path)
    names = preset_names()
    if name_or_path in names:
        return read_style(presets_dir() / f"{name_or_path}.yaml")
    raise StyleError(
        f"style {short_repr(name_or_path, 80)}: not a preset ({', '.join(names)}) nor a file"
    )


# --- measuring ---------------------------------------------------------------------------------


def _values(motions: Sequence[Motion], j: int) -> np.ndarray:
    return np.concatenate([angles[known[:, j].astype(bool), j] for angles, known in motions])


def _derivatives(motions: Sequence[Motion], j: int, order: int, rate_hz: float) -> np.ndarray:
    out = []
    for angles, known in motions:
        diff = np.abs(np.diff(angles[:, j], order)) * rate_hz**order
        valid = np.ones(len(diff), dtype=bool)
        for k in range(order + 1):
            valid &= known[k : len(known) - order + k, j].astype(bool)
        out.append(diff[valid])
    return np.concatenate(out) if out else np.zeros(0)


def _arm_values(motions: Sequence[Motion], robot: RobotDescription) -> tuple[np.ndarray, ...]:
    """Both shoulder pitches' known angles, and both elbows' bend (positive: more bent)."""
    pitch = [j for j, name in enumerate(robot.names) if name.endswith("ShoulderPitch")]
    bend = [j for j, name in enumerate(robot.names) if name.endswith("ElbowRoll")]
    if not pitch or not bend:
        return ()
    pitches = np.concatenate([_values(motions, j) for j in pitch])
    bends = np.concatenate(
        [(-1.0 if robot.names[j].startswith("L") else 1.0) * _values(motions, j) for j in bend]
    )
    return pitches, bends


def _arm_rest(motions: Sequence[Motion], robot: RobotDescription) -> tuple[float, float] | None:
    """The arms' rest (median shoulder pitch, median elbow bend) as measured, not bounded.

    The figure ``rest_bend_rad`` is bounded to its plausible range; the rest of a styled model
    (:func:`resolve`'s offsets) must not be, or a size that bends the model's elbows past the
    bound leaves them that far from the person's rest.
    """
    values = _arm_values(motions, robot)
    if not values:
        return None
    return float(np.median(values[0])), float(np.median(values[1]))


def measure_part(
    motions: Sequence[Motion],
    robot: RobotDescription,
    part: str,
    rate_hz: float = FRAME_RATE_HZ,
    min_seconds: float = MIN_PART_S,
) -> PartFigures | None:
    """The figures of ``part`` in ``motions``; None when observed less than ``min_seconds``."""
    joints = [int(j) for j in np.flatnonzero(robot.group_mask(part))]
    if not joints or not motions:
        return None
    seconds = min(sum(int(k[:, j].sum()) for _, k in motions) for j in joints) / rate_hz
    if seconds < min_seconds or seconds <= 0:
        return None
    variances = [np.var(_values(motions, j)) for j in joints]
    speeds = np.concatenate([_derivatives(motions, j, 1, rate_hz) for j in joints])
    accels = np.concatenate([_derivatives(motions, j, 2, rate_hz) for j in joints])
    extra: dict[str, float] = {}
    arm = _arm_values(motions, robot) if part == "arms" else ()
    if arm:
        extra = {
            "rest_pitch_rad": float(np.median(arm[0])),
            "rest_bend_rad": float(np.clip(np.median(arm[1]), *_BOUNDS["rest_bend_rad"])),
            "raise_p1_rad": float(np.percentile(arm[0], 1)),
        }

    def deciles(values: np.ndarray, name: str) -> tuple[float, ...]:
        low, high = _BOUNDS[name]
        return tuple(float(v) for v in np.clip(np.percentile(values, DECILES), low, high))

    return PartFigures(
        seconds=seconds,
        std_rad=float(np.clip(np.sqrt(np.mean(variances)), *_BOUNDS["std_rad"])),
        speed_deciles_rad_s=deciles(speeds, "speed_deciles_rad_s"),
        accel_deciles_rad_s2=deciles(accels, "accel_deciles_rad_s2"),
        **extra,
    )


def measure(
    motions: Sequence[Motion], robot: RobotDescription, rate_hz: float = FRAME_RATE_HZ
) -> dict[str, PartFigures]:
    """Figures of every part observed for at least :data:`MIN_PART_S` in ``motions``."""
    out = {}
    for part in JOINT_GROUPS:
        figures = measure_part(motions, robot, part, rate_hz)
        if figures is not None:
            out[part] = figures
    return out


# --- resolving ---------------------------------------------------------------------------------


def _styled(
    robot: RobotDescription, settings: StyleSettings, motions: Sequence[Motion], rate_hz: float
) -> list[Motion]:
    transform = StyleTransform(robot, settings, rate_hz)
    return [(transform.run(angles), known) for angles, known in motions]


def _log_ratios(target: PartFigures, model: PartFigures) -> tuple[np.ndarray, float]:
    """log(target / model) of the speed and acceleration deciles :data:`FIT_DECILES`, and std."""
    fitted = [DECILES.index(d) for d in FIT_DECILES]

    def upper(figures: PartFigures) -> np.ndarray:
        both = (figures.speed_deciles_rad_s, figures.accel_deciles_rad_s2)
        return np.array([values[k] for values in both for k in fitted])

    deciles = np.log(upper(target) / upper(model))
    return deciles, float(np.log(target.std_rad / model.std_rad))


def _loss(deciles: np.ndarray, std: float, log_gain: float) -> float:
    return 0.5 * float(np.mean(np.abs(deciles - log_gain))) + 0.5 * abs(std - log_gain)


def style_loss(target: PartFigures, model: PartFigures) -> float:
    """The loss of :func:`_fit_gain` of ``model``'s figures as they are (size 1) to ``target``."""
    return _loss(*_log_ratios(target, model), 0.0)


def _fit_gain(deciles: np.ndarray, std: float) -> tuple[float, float]:
    """The log gain that minimises the style loss for one tempo, and the loss.

    The loss is half the mean |log ratio| of the speed and acceleration deciles
    :data:`FIT_DECILES` plus half the |log ratio| of the std (every ratio scales by the gain
    alike: log gain shifts them all).
    """
    candidates = np.log(GAIN_GRID)
    losses = [_loss(deciles, std, c) for c in candidates]
    best = int(np.argmin(losses))
    return float(np.exp(candidates[best])), losses[best]


def _fit_pace(
    target: PartFigures,
    model_motions: Sequence[Motion],
    robot: RobotDescription,
    part: str,
    rate_hz: float,
    min_seconds: float = MIN_PART_S,
) -> tuple[float, float]:
    """The tempo and size of :func:`resolve` for one part (see there)."""
    fits = {}
    for tempo in TEMPO_GRID:
        settings = StyleSettings(**{f"{part}_tempo": tempo})
        motions = _styled(robot, settings, model_motions, rate_hz)
        styled = measure_part(motions, robot, part, rate_hz, min_seconds)
        if styled is not None:
            fits[tempo] = _fit_gain(*_log_ratios(target, styled))
    tempo = min(fits, key=lambda t: fits[t][1])
    if fits[tempo][1] >= 0.98 * fits[1.0][1]:
        tempo = 1.0
    return tempo, min(max(fits[tempo][0], 0.0), MAX_GAIN)


def resolve(
    person: Mapping[str, PartFigures],
    model_motions: Sequence[Motion],
    robot: RobotDescription,
    rate_hz: float = FRAME_RATE_HZ,
    paced: Collection[str] = (),
    min_seconds: float = MIN_PART_S,
) -> StyleSettings:
    """The filter settings that bring the model's motion closest to the person's figures.

    Per part, every tempo of :data:`TEMPO_GRID` styles ``model_motions``; for each, the size
    that minimises the loss of :func:`_fit_gain` (the upper speed and acceleration deciles and
    the std as ratios to the person's); the tempo and size of the smallest loss win (a tempo
    within 2 % of the identity's loss keeps the identity). Then the arms' rest offsets move the
    styled model's rest (as measured, :func:`_arm_rest`) onto the person's, and the height limit
    is the person's ``raise_p1_rad``. A part in ``paced`` keeps tempo and size 1: the model's
    motion already has the person's size and pace (a personal model's own sampling noise,
    :func:`~audio2pose_ros.style.personal.fit_arms_noise`); only its rest and height are set.

    Args:
        person: the person's figures per part (parts left out keep the model's motion).
        model_motions: the model's motion on reference speech, every frame known.
        robot: joint order, groups and neutral pose.
        rate_hz: frame rate of ``model_motions``.
        paced: parts whose tempo and size are left at 1.
        min_seconds: a part of ``model_motions`` shorter than this is left out (a fold of
            enrolment's cross-validation fits on a few seconds).

    Returns:
        The style settings, each inside its parameter's range.
    """
    values: dict[str, float] = {}
    for part, target in person.items():
        if measure_part(model_motions, robot, part, rate_hz, min_seconds) is None:
            continue
        tempo, gain = (
            (1.0, 1.0)
            if part in paced
            else _fit_pace(target, model_motions, robot, part, rate_hz, min_seconds)
        )
        values[f"{part}_tempo"] = tempo
        values[f"{part}_gain"] = round(gain, 4)
        if part == "arms" and target.rest_pitch_rad is not None:
            settings = StyleSettings(arms_tempo=tempo, arms_gain=gain)
            shaped = _arm_rest(_styled(robot, settings, model_motions, rate_hz), robot)
            assert shaped is not None
            assert target.rest_bend_rad is not None
            assert target.raise_p1_rad is not None

            def offset(value: float) -> float:
                return round(min(max(value, -MAX_REST_OFFSET_RAD), MAX_REST_OFFSET_RAD), 4)

            values["arms_rest_pitch_rad"] = offset(target.rest_pitch_rad - shaped[0])
            values["arms_rest_bend_rad"] = offset(target.rest_bend_rad - shaped[1])
            lowest = float(StyleSettings.arms_raise_limit_rad)
            values["arms_raise_limit_rad"] = round(max(target.raise_p1_rad, lowest), 4)
    return StyleSettings(**values)

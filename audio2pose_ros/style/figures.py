"""A style as measured figures of a person's motion, and how they resolve into filter settings.

A style file (a preset under ``config/styles/``, or ``style.yaml`` of a personal model written by
``audio2pose enroll``) holds, per observed part (head, arms, hip), figures measured from real
motion at 100 Hz (:func:`measure`):

- ``std_rad``: the part's size, the RMS over its joints of each joint's angle std;
- ``speed_p50_rad_s``, ``speed_p90_rad_s``, ``accel_p50_rad_s2``: percentiles of joint speed and
  acceleration pooled over the part's joints (seed 003 section 5.3 compares the same derivative
  distributions by the Hellinger distance);
- arms only: ``rest_pitch_rad`` (median shoulder pitch: where the hands rest), ``rest_bend_rad``
  (median elbow bend) and ``raise_p1_rad`` (1st percentile of the shoulder pitch: how high the
  arms go).

A part observed for less than :data:`MIN_PART_S` is left out, and a part left out keeps the
model's own motion. The figures are absolute, so a style means the same after a model is rebuilt:
:func:`resolve` turns them into :class:`~audio2pose_ros.motion.style.StyleSettings` against the
model's own figures, measured on the model's synthesis of the bundled speech
(:func:`~audio2pose_ros.style.personal.model_reference`): the tempo is chosen (bisection) so that
the ratio speed p50 / std of the styled model equals the person's, the size then so that the
std equals the person's; the arm rest offsets move the styled model's rest onto the person's,
and the height limit is the person's ``raise_p1_rad``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import yaml

from audio2pose_ros.errors import InputError, short_repr
from audio2pose_ros.motion.style import (
    MAX_GAIN,
    MAX_REST_OFFSET_RAD,
    MAX_TEMPO,
    MIN_TEMPO,
    StyleSettings,
    StyleTransform,
)
from audio2pose_ros.resources import share_path
from audio2pose_ros.robot.description import JOINT_GROUPS, RobotDescription
from audio2pose_ros.timebase import FRAME_RATE_HZ
from audio2pose_ros.yaml_files import read_yaml_file

Motion = tuple[np.ndarray, np.ndarray]  # (T, J) angles in radians, (T, J) known mask
STYLE_FORMAT = 1
MIN_PART_S = 5.0  # a part observed for less than this is not measured (not adapted)
TEMPO_STEPS = 10  # bisection steps of the tempo (to 1.8 / 2**10 of the tempo range)
MAX_STYLE_BYTES = 65536
# plausible bounds of the figures in a style file (hostile or broken files are refused)
_BOUNDS = {
    "seconds": (0.0, 1e6),
    "std_rad": (1e-4, 2.0),
    "speed_p50_rad_s": (1e-5, 20.0),
    "speed_p90_rad_s": (1e-5, 40.0),
    "accel_p50_rad_s2": (1e-4, 2000.0),
    "rest_pitch_rad": (-2.1, 2.1),
    "rest_bend_rad": (-0.1, 1.6),
    "raise_p1_rad": (-2.1, 2.1),
}
_ARM_FIELDS = ("rest_pitch_rad", "rest_bend_rad", "raise_p1_rad")


class StyleError(InputError):
    """A style file, preset name or figure is refused (the message says which and why)."""


@dataclass(frozen=True)
class PartFigures:
    """Measured figures of one part (see the module docstring); arm fields are None elsewhere."""

    seconds: float
    std_rad: float
    speed_p50_rad_s: float
    speed_p90_rad_s: float
    accel_p50_rad_s2: float
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
            if (
                isinstance(value, bool)
                or not isinstance(value, int | float)
                or not math.isfinite(value)
                or not low <= value <= high
            ):
                raise StyleError(
                    f"style figure {name}: {short_repr(value, 40)} is not a number in "
                    f"[{low:g}, {high:g}]"
                )

    def as_dict(self) -> dict[str, float]:
        """The figures to write (arm fields only where set), rounded for a readable file."""
        return {k: round(float(v), 5) for k, v in asdict(self).items() if v is not None}


@dataclass(frozen=True)
class StyleFile:
    """A named style: its figures per part, and where they come from.

    Attributes:
        name: short name (a preset's file stem, or the enrolled person's folder name).
        description: one line for people.
        source: the recording(s) measured, with their licence or attribution.
        command: the command that re-measures the figures.
        parts: part -> figures; parts not present are not adapted.
    """

    name: str
    description: str
    source: str
    command: str
    parts: Mapping[str, PartFigures]

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
        return yaml.safe_dump(document, sort_keys=False, width=100)

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
    )


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


def measure_part(
    motions: Sequence[Motion], robot: RobotDescription, part: str, rate_hz: float = FRAME_RATE_HZ
) -> PartFigures | None:
    """The figures of ``part`` in ``motions``; None when observed less than :data:`MIN_PART_S`."""
    joints = [int(j) for j in np.flatnonzero(robot.group_mask(part))]
    if not joints or not motions:
        return None
    seconds = min(sum(int(k[:, j].sum()) for _, k in motions) for j in joints) / rate_hz
    if seconds < MIN_PART_S:
        return None
    variances = [np.var(_values(motions, j)) for j in joints]
    speeds = np.concatenate([_derivatives(motions, j, 1, rate_hz) for j in joints])
    accels = np.concatenate([_derivatives(motions, j, 2, rate_hz) for j in joints])
    extra: dict[str, float] = {}
    if part == "arms":
        pitch = [j for j in joints if robot.names[j].endswith("ShoulderPitch")]
        bend = [j for j in joints if robot.names[j].endswith("ElbowRoll")]
        if pitch and bend:
            pitches = np.concatenate([_values(motions, j) for j in pitch])
            bends = np.concatenate(
                [
                    (-1.0 if robot.names[j].startswith("L") else 1.0) * _values(motions, j)
                    for j in bend
                ]
            )
            extra = {
                "rest_pitch_rad": float(np.median(pitches)),
                "rest_bend_rad": float(np.clip(np.median(bends), *_BOUNDS["rest_bend_rad"])),
                "raise_p1_rad": float(np.percentile(pitches, 1)),
            }
    floor = _BOUNDS["std_rad"][0]
    return PartFigures(
        seconds=seconds,
        std_rad=max(float(np.sqrt(np.mean(variances))), floor),
        speed_p50_rad_s=max(float(np.percentile(speeds, 50)), _BOUNDS["speed_p50_rad_s"][0]),
        speed_p90_rad_s=max(float(np.percentile(speeds, 90)), _BOUNDS["speed_p90_rad_s"][0]),
        accel_p50_rad_s2=max(float(np.percentile(accels, 50)), _BOUNDS["accel_p50_rad_s2"][0]),
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


def resolve(
    person: Mapping[str, PartFigures],
    model_motions: Sequence[Motion],
    robot: RobotDescription,
    rate_hz: float = FRAME_RATE_HZ,
) -> StyleSettings:
    """The filter settings that bring the model's motion to the person's figures.

    Args:
        person: the person's figures per part (parts left out keep the model's motion).
        model_motions: the model's motion on reference speech, every frame known.
        robot: joint order, groups and neutral pose.
        rate_hz: frame rate of ``model_motions``.

    Returns:
        The style settings, each inside its parameter's range.
    """
    values: dict[str, float] = {}
    for part, target in person.items():
        model = measure_part(model_motions, robot, part, rate_hz)
        if model is None:
            continue
        wanted = (target.speed_p50_rad_s / target.std_rad) / (model.speed_p50_rad_s / model.std_rad)

        def frequency(tempo: float, part: str = part) -> tuple[float, PartFigures]:
            styled = _styled(
                robot, StyleSettings(**{f"{part}_tempo": tempo}), model_motions, rate_hz
            )
            figures = measure_part(styled, robot, part, rate_hz)
            assert figures is not None
            return figures.speed_p50_rad_s / figures.std_rad, figures

        base = model.speed_p50_rad_s / model.std_rad
        low, high = MIN_TEMPO, MAX_TEMPO
        for _ in range(TEMPO_STEPS):
            middle = 0.5 * (low + high)
            if frequency(middle)[0] / base < wanted:
                low = middle
            else:
                high = middle
        tempo = 0.5 * (low + high)
        tempo = 1.0 if abs(tempo - 1.0) < 0.01 else tempo
        paced = frequency(tempo)[1]
        gain = min(max(target.std_rad / paced.std_rad, 0.0), MAX_GAIN)
        values[f"{part}_tempo"] = round(tempo, 4)
        values[f"{part}_gain"] = round(gain, 4)
        if part == "arms" and target.rest_pitch_rad is not None:
            settings = StyleSettings(arms_tempo=values["arms_tempo"], arms_gain=gain)
            shaped = measure_part(_styled(robot, settings, model_motions, rate_hz), robot, part)
            assert shaped is not None
            assert shaped.rest_pitch_rad is not None
            assert shaped.rest_bend_rad is not None
            assert target.rest_bend_rad is not None
            assert target.raise_p1_rad is not None

            def offset(value: float) -> float:
                return round(min(max(value, -MAX_REST_OFFSET_RAD), MAX_REST_OFFSET_RAD), 4)

            values["arms_rest_pitch_rad"] = offset(target.rest_pitch_rad - shaped.rest_pitch_rad)
            values["arms_rest_bend_rad"] = offset(target.rest_bend_rad - shaped.rest_bend_rad)
            lowest = float(StyleSettings.arms_raise_limit_rad)
            values["arms_raise_limit_rad"] = round(max(target.raise_p1_rad, lowest), 4)
    return StyleSettings(**values)

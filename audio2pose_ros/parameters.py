"""Parameters declared once: name, type, default, range, description, whether it may change live.

A settings dataclass of the core (``MotionFilterSettings``, ``LimitSettings``, ...) declares each
field with :func:`param`; the field's default, type and metadata are then the single definition
that the node's ParameterDescriptors (``audio2pose_ros.ros.node_parameters``), the settings
validation (:func:`validate_settings`, called from ``__post_init__``), ``config/pepper.yaml`` and
the parameter page (``doc/parameters.md``) are checked against. This module does not import rclpy.

Rules every value goes through (:meth:`ParameterSpec.validate`):

- the type is the default's type; an integer is accepted where a float is meant (YAML ``0``
  for ``0.0``), a bool never counts as a number;
- floats must be finite (NaN and inf are refused), inside ``[minimum, maximum]`` where given
  and outside ``excluded`` where given (a gap of meaningless values inside the range);
- strings with ``choices`` must be one of them.

A refused value raises :class:`~audio2pose_ros.errors.ConfigurationError` with one line naming
the parameter, the value (cut short: :func:`~audio2pose_ros.errors.short_repr`) and what is
allowed.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any, TypeVar

from audio2pose_ros.errors import ConfigurationError, short_repr

__all__ = [
    "ParameterSpec",
    "ParameterValue",
    "param",
    "settings_from",
    "settings_with",
    "specs_of",
    "validate_settings",
    "validate_values",
]

ParameterValue = bool | int | float | str
SettingsT = TypeVar("SettingsT")
_METADATA_KEY = "audio2pose_parameter"


@dataclass(frozen=True)
class ParameterSpec:
    """One parameter: everything a node, a YAML file and the docs need to know about it.

    Attributes:
        name: parameter name (as in the YAML file under ``ros__parameters``).
        default: default value; its type is the parameter's type.
        description: one line for ParameterDescriptor.description and the docs.
        minimum: inclusive lower bound for numbers, or None.
        maximum: inclusive upper bound for numbers, or None.
        excluded: ``(low, high)``: numbers with low <= value < high are refused although
            inside ``[minimum, maximum]`` (None: no gap).
        choices: allowed values of a string parameter (empty: any string).
        read_only: True when the value cannot change while the node runs (set at start-up).
        unit: unit shown in documentation ('' when dimensionless).
    """

    name: str
    default: ParameterValue
    description: str
    minimum: float | None = None
    maximum: float | None = None
    excluded: tuple[float, float] | None = None
    choices: tuple[str, ...] = ()
    read_only: bool = False
    unit: str = ""

    def __post_init__(self) -> None:
        """The default itself must pass the rules."""
        self.validate(self.default)

    @property
    def kind(self) -> type:
        """Python type of the value: bool, int, float or str."""
        return type(self.default)

    def allowed(self) -> str:
        """What values are allowed, in words (for error messages and documentation)."""
        if self.kind is bool:
            return "true or false"
        if self.kind is str:
            return f"one of {list(self.choices)}" if self.choices else "a string"
        low = "-inf" if self.minimum is None else f"{self.minimum:g}"
        high = "inf" if self.maximum is None else f"{self.maximum:g}"
        what = "an integer" if self.kind is int else "a finite number"
        gap = (
            ""
            if self.excluded is None
            else f" but not in [{self.excluded[0]:g}, {self.excluded[1]:g})"
        )
        return f"{what} in [{low}, {high}]{gap}"

    def validate(self, value: object) -> ParameterValue:
        """Return ``value`` converted to the parameter's type, or raise ConfigurationError.

        Raises:
            ConfigurationError: wrong type, non-finite, out of range or not a choice; the
                message names the parameter, the value and what is allowed.
        """
        kind = self.kind
        problem = ""
        converted: ParameterValue | None = None
        if kind is bool:
            if isinstance(value, bool):
                converted = value
        elif kind is str:
            if isinstance(value, str):
                converted = value
                if self.choices and value not in self.choices:
                    problem = "is not allowed"
        elif isinstance(value, int | float) and not isinstance(value, bool):
            if kind is int and not isinstance(value, int):
                problem = "is not an integer"
            elif not math.isfinite(value):
                problem = "is not finite"
            else:
                converted = kind(value)
                if (self.minimum is not None and value < self.minimum) or (
                    self.maximum is not None and value > self.maximum
                ):
                    problem = "is out of range"
                elif self.excluded is not None and self.excluded[0] <= value < self.excluded[1]:
                    problem = "is in the excluded gap"
        if converted is None and not problem:
            problem = f"has the wrong type ({type(value).__name__})"
        if problem:
            raise ConfigurationError(
                f"parameter {self.name}: value {short_repr(value, 80)} {problem}; "
                f"allowed: {self.allowed()}"
            )
        assert converted is not None
        return converted


def param(
    description: str,
    *,
    minimum: float | None = None,
    maximum: float | None = None,
    excluded: tuple[float, float] | None = None,
    choices: Iterable[str] = (),
    read_only: bool = False,
    unit: str = "",
) -> dict[str, Any]:
    """Field metadata for a settings dataclass field declared as a node parameter.

    Use: ``rate_hz: float = field(default=100.0, metadata=param("...", minimum=1.0))``.
    """
    return {
        _METADATA_KEY: {
            "description": description,
            "minimum": minimum,
            "maximum": maximum,
            "excluded": excluded,
            "choices": tuple(choices),
            "read_only": read_only,
            "unit": unit,
        }
    }


def specs_of(settings_class: type) -> tuple[ParameterSpec, ...]:
    """The ParameterSpecs of a settings dataclass, one per field declared with :func:`param`."""
    specs = []
    for field in dataclasses.fields(settings_class):
        meta = field.metadata.get(_METADATA_KEY)
        if meta is None:
            continue
        if field.default is dataclasses.MISSING:
            raise TypeError(f"{settings_class.__name__}.{field.name} needs a default")
        specs.append(ParameterSpec(name=field.name, default=field.default, **meta))
    return tuple(specs)


def settings_from(settings_class: type[SettingsT], values: Mapping[str, object]) -> SettingsT:
    """An instance of a settings dataclass from the values of its fields in ``values``.

    Every node builds its settings this way from its parameter values (names of other settings
    classes in ``values``, and fields not declared with :func:`param`, are ignored); fields
    missing from ``values`` keep their defaults.

    Raises:
        ConfigurationError: a value is refused by the class's validation.
    """
    names = {spec.name for spec in specs_of(settings_class)}
    return settings_class(**{k: v for k, v in values.items() if k in names})


def settings_with(settings: SettingsT, changes: Mapping[str, object]) -> SettingsT:
    """A copy of ``settings`` with the values of its :func:`param` fields in ``changes``.

    A live change: names of other settings classes in ``changes`` are ignored.

    Raises:
        ConfigurationError: a changed value is refused by the class's validation.
    """
    names = {spec.name for spec in specs_of(type(settings))}
    ours = {k: v for k, v in changes.items() if k in names}
    return dataclasses.replace(settings, **ours) if ours else settings  # type: ignore[type-var]


def validate_values(
    specs: Iterable[ParameterSpec], values: Mapping[str, object]
) -> dict[str, ParameterValue]:
    """Validate ``values`` (a subset of the specs' names) and return them converted.

    Raises:
        ConfigurationError: a name is unknown or a value is refused (first problem only).
    """
    by_name = {spec.name: spec for spec in specs}
    out: dict[str, ParameterValue] = {}
    for name, value in values.items():
        if name not in by_name:
            raise ConfigurationError(
                f"unknown parameter {short_repr(name, 80)}; known: {sorted(by_name)}"
            )
        out[name] = by_name[name].validate(value)
    return out


def validate_settings(settings: object) -> None:
    """Check every :func:`param` field of a settings dataclass instance (call in __post_init__).

    Raises:
        ConfigurationError: the first field whose value is refused.
    """
    for spec in specs_of(type(settings)):
        value = getattr(settings, spec.name)
        converted = spec.validate(value)
        if converted is not value and type(converted) is not type(value):
            # an int given for a float field: store the float (frozen dataclasses too)
            object.__setattr__(settings, spec.name, converted)

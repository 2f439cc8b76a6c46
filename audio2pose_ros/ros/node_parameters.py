"""Declare a node's parameters from their ParameterSpecs; validate at start-up and at run time.

Each :class:`~audio2pose_ros.parameters.ParameterSpec` becomes one declared parameter with a
ParameterDescriptor (description, type, range, read_only, and the allowed values in words as
``additional_constraints``). Values are validated by the spec, not by rclpy's static typing, so
that an integer is accepted where a float is meant (``arms_gain: 0``) and every refusal names the
parameter, the value and the allowed range in one line:

- at start-up, :class:`NodeParameters` raises :class:`~audio2pose_ros.errors.ConfigurationError`
  (``run_node`` turns it into one log line and exit status ``EXIT_CONFIGURATION_ERROR``);
- at run time, ``ros2 param set`` / set_parameters goes through an on-set callback that validates
  and hands the new values to the node's ``apply`` callback. ``successful=True`` means the change
  takes effect from the node's next tick; a refusal carries the reason. Read-only parameters are
  refused by rclpy itself.
"""

from __future__ import annotations

import math
import re
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.files import read_yaml_file
from audio2pose_ros.parameters import ParameterSpec, ParameterValue
from audio2pose_ros.ros.parameter_names import NODE_PARAMETER_NAMES

__all__ = ["NodeParameters", "check_parameter_files", "descriptor_of", "parameter_files"]

_TYPES = {
    bool: ParameterType.PARAMETER_BOOL,
    int: ParameterType.PARAMETER_INTEGER,
    float: ParameterType.PARAMETER_DOUBLE,
    str: ParameterType.PARAMETER_STRING,
}


def descriptor_of(spec: ParameterSpec) -> ParameterDescriptor:
    """The ParameterDescriptor advertised for ``spec`` (``ros2 param describe`` shows it)."""
    descriptor = ParameterDescriptor(
        name=spec.name,
        type=_TYPES[spec.kind],
        description=spec.description + (f" ({spec.unit})" if spec.unit else ""),
        additional_constraints=f"allowed: {spec.allowed()}",
        read_only=spec.read_only,
        # Typing is checked by the spec, which also accepts an integer for a float.
        dynamic_typing=True,
    )
    if spec.kind is float and (spec.minimum is not None or spec.maximum is not None):
        low = -sys.float_info.max if spec.minimum is None else float(spec.minimum)
        high = sys.float_info.max if spec.maximum is None else float(spec.maximum)
        descriptor.floating_point_range = [FloatingPointRange(from_value=low, to_value=high)]
    elif spec.kind is int and (spec.minimum is not None or spec.maximum is not None):
        low_i = -(2**63) if spec.minimum is None else int(spec.minimum)
        high_i = 2**63 - 1 if spec.maximum is None else int(spec.maximum)
        descriptor.integer_range = [IntegerRange(from_value=low_i, to_value=high_i, step=0)]
    return descriptor


def parameter_files(argv: Sequence[str]) -> list[Path]:
    """The ``--params-file`` arguments of a node's command line (after ``--ros-args``)."""
    files: list[Path] = []
    in_ros_args = False
    for i, arg in enumerate(argv):
        if arg == "--ros-args":
            in_ros_args = True
        elif arg == "--":
            in_ros_args = False
        elif in_ros_args and arg == "--params-file" and i + 1 < len(argv):
            files.append(Path(argv[i + 1]))
    return files


def _section_pattern(key: str) -> re.Pattern[str]:
    """Rcl's node-name wildcards: ``**`` any namespaces, ``*`` one name, ``/`` optional first."""
    name = key if key.startswith("/") else f"/{key}"
    parts = [".*" if p == "**" else re.escape(p).replace(r"\*", "[^/]*") for p in name.split("/")]
    return re.compile("/".join(parts).replace("/.*", "(/.*)?") + "$")


def check_parameter_files(
    node_name: str, namespace: str, specs: Iterable[ParameterSpec], files: Sequence[Path]
) -> None:
    """Check every value the parameter files give this node against its declarations.

    rcl merges the files of a node's command line and drops, without a word, a value whose type
    differs from the same parameter's in an earlier file (``rate_hz: fast`` after the package's
    ``rate_hz: 100.0``): the node would run with a value its user did not write. Here every
    section that applies to the node (``/**``, its name, its fully qualified name, wildcards) is
    read with the project's bounded YAML reader and every value of a declared parameter is
    validated. Names the node does not declare are left alone: sections are shared (``/**``),
    and launch passes one override set to every node.

    Raises:
        ConfigurationError: naming the file, the parameter and what is allowed.
    """
    by_name = {spec.name: spec for spec in specs}
    fully_qualified = f"{namespace.rstrip('/')}/{node_name}"
    for file in files:
        document = read_yaml_file(file, "parameters", ConfigurationError)
        if not isinstance(document, Mapping):
            continue  # rcl refuses such a file itself, with its own message
        for key, section in document.items():
            if not isinstance(key, str) or not _section_pattern(key).match(fully_qualified):
                continue
            values = section.get("ros__parameters") if isinstance(section, Mapping) else None
            if not isinstance(values, Mapping):
                continue
            for name, value in values.items():
                spec = by_name.get(str(name))
                if spec is None:
                    continue  # another node's parameter (a shared section), or a ROS option
                try:
                    spec.validate(value)
                except ConfigurationError as exc:
                    raise ConfigurationError(f"{file}: {exc}") from None


# Parameters rclpy itself reads from a node's overrides, which no spec declares.
ROS_PARAMETERS = frozenset({"use_sim_time", "start_type_description_service"})
ROS_PARAMETER_PREFIXES = ("qos_overrides.",)


def unknown_parameter_warnings(
    given: Iterable[str], specs: Mapping[str, ParameterSpec]
) -> list[str]:
    """One line per given parameter name that no node of this package declares: a typo.

    rclpy ignores, without a word, an override it has no declaration for, so
    ``-p feature_limt_sd:=3`` would leave the node on its default. A name another node of the
    package declares passes (launch and ``/**`` sections give every node the same set), as do
    rclpy's own (:data:`ROS_PARAMETERS`, ``qos_overrides.*``). The other nodes' declarations
    are the generated :data:`~audio2pose_ros.ros.parameter_names.NODE_PARAMETER_NAMES`, so that
    this module, which every node imports, imports no node.
    """
    strangers = sorted(
        name
        for name in given
        if name not in specs
        and name not in ROS_PARAMETERS
        and not name.startswith(ROS_PARAMETER_PREFIXES)
    )
    lines = []
    for name in strangers:
        if name in NODE_PARAMETER_NAMES:
            continue
        import difflib  # here: a node whose parameters are all known never needs it

        close = difflib.get_close_matches(name, list(specs), n=1) or difflib.get_close_matches(
            name, sorted(NODE_PARAMETER_NAMES), n=1
        )
        hint = f"; did you mean {close[0]}?" if close else ""
        lines.append(
            f"parameter {name} is not a parameter of any audio2pose_ros node and was ignored" + hint
        )
    return lines


LOG_SPACING_S = 1.0  # run-time parameter changes are logged at most this often, summarised


class _ChangeLog:
    """Run-time parameter changes and refusals, logged as at most one summary per period.

    The first change after a quiet period is logged at once; later ones within
    :data:`LOG_SPACING_S` are gathered (the newest value of each parameter, the number of
    requests) and logged by :meth:`flush`, which the node's timer calls :data:`LOG_SPACING_S`
    after the first of them. The timer is armed only while something is gathered: a node
    whose parameters do not change is never woken for it.
    """

    def __init__(self, node: Node) -> None:
        self.node = node
        self.values: dict[str, ParameterValue] = {}
        self.changes = 0
        self.refusals = 0
        self.last_refusal = ""
        self.logged_s = -math.inf
        self.timer = node.create_timer(LOG_SPACING_S, self._flush_due)
        self.timer.cancel()  # armed by the first change gathered

    def changed(self, changes: Mapping[str, ParameterValue]) -> None:
        """Record a request's changes (none: nothing to log)."""
        if changes:
            self.values.update(changes)
            self.changes += 1
            self._log_if_due()

    def refused(self, reason: str) -> None:
        """Record a refused request."""
        self.refusals += 1
        self.last_refusal = reason
        self._log_if_due()

    def _log_if_due(self) -> None:
        if time.monotonic() - self.logged_s >= LOG_SPACING_S:
            self.flush()
        elif self.timer.is_canceled():
            self.timer.reset()

    def _flush_due(self) -> None:
        self.timer.cancel()
        self.flush()

    def flush(self) -> None:
        """Log what was gathered since the last line, if anything."""
        logger = self.node.get_logger()
        if self.values:
            times = f" ({self.changes} requests)" if self.changes > 1 else ""
            logger.info(
                "parameters changed: "
                + ", ".join(f"{k}={v!r}" for k, v in self.values.items())
                + times
            )
        if self.refusals:
            times = f" ({self.refusals} requests refused)" if self.refusals > 1 else ""
            logger.warning(f"parameter change refused: {self.last_refusal}{times}")
        if self.values or self.refusals:
            self.logged_s = time.monotonic()
        self.values, self.changes, self.refusals = {}, 0, 0


class NodeParameters:
    """The declared, validated parameters of one node.

    Attributes:
        values: the current validated value of every parameter, by name.
    """

    def __init__(
        self,
        node: Node,
        specs: Iterable[ParameterSpec],
        apply: Callable[[Mapping[str, ParameterValue]], None] | None = None,
    ) -> None:
        """Declare every spec and validate its start-up value (override, file or default).

        Args:
            node: the node that owns the parameters.
            specs: the parameters; names must be unique.
            apply: called at run time with the changed, validated values (only the parameters
                that are not read-only reach it). It may raise ConfigurationError to refuse a
                combination of values; it must not leave the node half-changed when it does.
                Without ``apply`` every parameter is effectively read-only and run-time changes
                are refused.

        Raises:
            ConfigurationError: a start-up value is refused (the message names it).
        """
        self.node = node
        self.specs = {spec.name: spec for spec in specs}
        self._apply = apply
        overrides = getattr(node, "_parameter_overrides", {})
        check_parameter_files(
            node.get_name(), node.get_namespace(), self.specs.values(), parameter_files(sys.argv)
        )
        self.values: dict[str, ParameterValue] = {}
        for name, spec in self.specs.items():
            if name in overrides:  # validate first: our message beats rclpy's range message
                spec.validate(overrides[name].value)
            try:
                declared: Parameter[Any] = node.declare_parameter(
                    name, spec.default, descriptor_of(spec)
                )
                value: ParameterValue = declared.value
            except (InvalidParameterValueException, InvalidParameterTypeException) as exc:
                raise ConfigurationError(f"parameter {name}: {exc}") from None
            self.values[name] = spec.validate(value)
        for line in unknown_parameter_warnings(overrides, self.specs):
            node.get_logger().warning(line)
        self._log = _ChangeLog(node)
        node.add_on_set_parameters_callback(self._on_set)

    def __getitem__(self, name: str) -> ParameterValue:
        """Current value of parameter ``name``."""
        return self.values[name]

    def _on_set(self, parameters: list[Parameter[Any]]) -> SetParametersResult:
        """Validate a request and hand its changes to ``apply``; bounded work, throttled log.

        A value equal to the current one is no change: a request of only such values costs its
        validation and nothing else. Changes and refusals are logged in one summary line per
        :data:`LOG_SPACING_S` (and at the end of a burst), not one line per request: a storm
        of requests (a slider dragged, a script in a loop) costs the node no log output.
        """
        changes: dict[str, ParameterValue] = {}
        try:
            for parameter in parameters:
                spec = self.specs.get(parameter.name)
                if spec is None:
                    continue  # not ours (e.g. use_sim_time)
                if spec.read_only or self._apply is None:
                    raise ConfigurationError(
                        f"parameter {spec.name} cannot change while the node runs"
                    )
                value = spec.validate(parameter.value)
                if value != self.values[spec.name]:  # both validated: of the spec's type
                    changes[spec.name] = value
            if changes and self._apply is not None:
                self._apply(changes)
        except ConfigurationError as exc:
            self._log.refused(str(exc))
            return SetParametersResult(successful=False, reason=str(exc))
        self.values.update(changes)
        self._log.changed(changes)
        return SetParametersResult(successful=True)

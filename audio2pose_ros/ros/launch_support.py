"""What ``launch/pepper.launch.py`` decides, as plain functions that need neither launch nor rclpy.

The launch file reads its arguments as strings, hands them to :func:`plan_launch` and builds its
actions from the :class:`LaunchPlan` it gets back; a crashed node is restarted or the launch is
stopped as :class:`RespawnBudget` decides. Keeping the decisions here lets them be tested where
``launch`` is not installed, and keeps them identical on every distro the package supports
(Humble, Jazzy, Kilted, Rolling):

- Booleans follow launch's own ``IfCondition`` rule (:func:`parse_bool`). ``AndSubstitution``
  is not used to combine them: on Humble it reads its operands as YAML and refuses ``1``, which
  ``IfCondition`` accepts.
- Namespaces and topic names are normalised (``/mic/`` -> ``/mic``) or refused in one line.
- The parameters file must exist and parse as a YAML mapping before any node starts: rcl would
  otherwise fail inside every node at start-up (a YAML error) or ignore it (a missing file).
- ``model_path`` is passed to the nodes only when the launch argument is not empty, so the
  precedence is ROS's own: launch argument > parameters file > package default. A personal
  model folder (``audio2pose enroll``) there means its checkpoint and its style.
- ``style`` (a preset, a style file or a personal model folder) becomes the motion filter's
  style parameters, resolved against the model (:func:`style_parameters`); they win over the
  parameters file and stay settable live.
- Crashed nodes are restarted with back-off and a bounded count instead of launch's
  ``respawn=True`` (``respawn_max_retries`` does not exist on Humble); a node that exits with
  :data:`EXIT_CONFIGURATION_ERROR` is never restarted.
"""

from __future__ import annotations

import re
import signal
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from audio2pose_ros import topics
from audio2pose_ros.errors import EXIT_CONFIGURATION_ERROR, Audio2PoseError, ConfigurationError
from audio2pose_ros.files import MAX_YAML_BYTES, load_yaml_text
from audio2pose_ros.voice.naoqi import parse_voice_out

__all__ = [
    "ARGUMENTS",
    "CONSOLE_EXECUTABLE",
    "CONTROLLER_NAME",
    "CONTROLLER_TOPIC",
    "EXIT_CONFIGURATION_ERROR",
    "GaveUpError",
    "LaunchPlan",
    "RespawnBudget",
    "RespawnDecision",
    "check_params_file",
    "describe_exit",
    "model_path_override",
    "normalize_namespace",
    "normalize_topic",
    "parse_bool",
    "plan_launch",
    "style_parameters",
]

# ros2_control for Pepper (naoqi_driver's ros2_control work) runs this controller at 50 Hz;
# config/ros2_controllers.yaml declares it under the same name.
CONTROLLER_NAME = "pepper_joint_trajectory_controller"
CONTROLLER_TOPIC = f"/{CONTROLLER_NAME}/joint_trajectory"
SIM_CHOICES = ("none", "gz", "pybullet")
AUDIO_INPUTS = (topics.AUDIO, topics.AUDIO_INFO)  # the features node's inputs moved by audio_ns
# The launch file's arguments, all read by plan_launch.
ARGUMENTS = (
    "params_file",
    "model_path",
    "style",
    "audio_ns",
    "controller_topic",
    "rviz",
    "robot_state_publisher",
    "sim",
    "diagnostic_aggregator",
    "single_process",
    "console",
    "voice_out",
)
# console:=true starts this executable (the operator's web console).
CONSOLE_EXECUTABLE = "console_node"
# single_process:=true runs this module's three nodes in one process (the smallest footprint).
SINGLE_PROCESS_MODULE = "audio2pose_ros.ros.nodes.single_process"

# launch.conditions.IfCondition: the expanded text, stripped and lower-cased, must be one of these.
_TRUE = ("true", "1")
_FALSE = ("false", "0")
# One token of a ROS 2 name (design.ros2.org "Topic and Service name mapping to DDS").
_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def parse_bool(argument: str, text: str) -> bool:
    """Read a boolean launch argument exactly as launch's ``IfCondition`` reads it.

    Args:
        argument: the launch argument's name, for the error message.
        text: its value; surrounding blanks and letter case are ignored.

    Returns:
        True for ``true`` / ``1``, False for ``false`` / ``0`` (``True``, ``FALSE``, ...).

    Raises:
        ConfigurationError: any other text, named with the argument and the accepted words.

    """
    word = text.strip().lower()
    if word in _TRUE:
        return True
    if word in _FALSE:
        return False
    raise ConfigurationError(
        f"launch argument {argument}:={text!r} is not a boolean (accepted: true, false, 1, 0; "
        "any letter case)"
    )


def _tokens(argument: str, text: str) -> tuple[bool, list[str]]:
    """(absolute, tokens) of a ROS name, empty tokens (``//``, trailing ``/``) dropped."""
    name = text.strip()
    tokens = [token for token in name.split("/") if token]
    bad = [token for token in tokens if not _TOKEN.fullmatch(token)]
    if bad:
        raise ConfigurationError(
            f"launch argument {argument}:={text!r} is not a valid ROS name: {bad[0]!r} must "
            "start with a letter or '_' and hold only letters, digits and '_'"
        )
    return name.startswith("/"), tokens


def normalize_namespace(argument: str, text: str) -> str:
    """A namespace with no trailing or doubled ``/``: ``/mic/`` -> ``/mic``, ``/`` -> ``""``.

    A relative namespace stays relative (it resolves inside the namespace the launch file is
    included in).

    Args:
        argument: the launch argument's name, for the error message.
        text: the namespace as given.

    Returns:
        ``""`` for the root namespace, else ``/a/b`` or ``a/b``.

    Raises:
        ConfigurationError: a token is not a valid ROS name token.

    """
    absolute, tokens = _tokens(argument, text)
    if not tokens:
        return ""
    return ("/" if absolute else "") + "/".join(tokens)


def normalize_topic(argument: str, text: str) -> str:
    """A topic name with no trailing or doubled ``/``; absolute or relative as given.

    Raises:
        ConfigurationError: the name is empty or a token is not a valid ROS name token.

    """
    topic = normalize_namespace(argument, text)
    if not topic:
        raise ConfigurationError(f"launch argument {argument}:={text!r} names no topic")
    return topic


def topic_in(namespace: str, name: str) -> str:
    """``name`` inside a namespace returned by :func:`normalize_namespace`."""
    return f"{namespace}/{name}" if namespace else f"/{name}"


def check_params_file(path: str) -> Path:
    """Refuse a parameters file rcl could not use, before any node starts.

    rcl reads the file inside every node: a YAML error makes each node fail at start-up, and a
    missing file only warns and leaves the nodes on their built-in defaults.

    Args:
        path: the ``params_file`` launch argument.

    Returns:
        The file's path.

    Raises:
        ConfigurationError: the file does not exist, cannot be read, is not valid YAML, or is
            not a mapping of node names (nested in namespaces) to their ``ros__parameters``
            mappings, the layout rcl reads.

    """
    file = Path(path.strip()).expanduser()
    if not path.strip():
        raise ConfigurationError("launch argument params_file:='' names no file")
    if not file.is_file():
        raise ConfigurationError(f"params_file {file}: no such file")
    if file.stat().st_size > MAX_YAML_BYTES:
        raise ConfigurationError(f"params_file {file}: larger than {MAX_YAML_BYTES} bytes")
    try:
        content = load_yaml_text(file.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigurationError(f"params_file {file}: cannot be read ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise ConfigurationError(f"params_file {file}: not UTF-8 text") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ConfigurationError(f"params_file {file}: not valid YAML{where}: {problem}") from None
    if content is None:  # empty: rcl accepts it, nothing is set
        return file
    if not isinstance(content, Mapping):
        raise ConfigurationError(
            f"params_file {file}: expected a mapping of node names to ros__parameters, "
            f"got {type(content).__name__}"
        )
    _check_node_sections(file, content, "")
    return file


def _check_node_sections(file: Path, section: Mapping[object, object], where: str) -> None:
    """Every key is a namespace / node level or ``ros__parameters``, each a mapping or empty.

    rcl itself accepts a list or a scalar there and ignores it: the parameters the user meant
    would silently not be set.
    """
    for key, value in section.items():
        inside = f"{where}/{key}" if where else str(key)
        if value is None:
            continue
        if not isinstance(value, Mapping):
            expected = "parameters" if key == "ros__parameters" else "a node's ros__parameters"
            raise ConfigurationError(
                f"params_file {file}: {inside} must be a mapping of {expected}, "
                f"got {type(value).__name__}"
            )
        if key != "ros__parameters":
            _check_node_sections(file, value, inside)


def model_path_override(text: str) -> dict[str, str]:
    """The ``model_path`` parameter to pass on top of the parameters file.

    Returns:
        ``{}`` for an empty argument (the parameters file, else the package default, decides),
        else ``{"model_path": text}``: an explicit launch argument wins.

    """
    model_path = text.strip()
    return {"model_path": model_path} if model_path else {}


def style_parameters(
    style: str, model_path: Mapping[str, str]
) -> tuple[dict[str, str], dict[str, float]]:
    """The checkpoint override and the filter's style parameters of ``style`` and ``model_path``.

    Args:
        style: the ``style`` launch argument: '' (none), a preset name, a style file or a
            personal model folder.
        model_path: :func:`model_path_override` of the ``model_path`` argument; a personal model
            folder there stands for its checkpoint and (unless ``style`` is given) its style.

    Returns:
        ``(model_path, parameters)``: the ``model_path`` override to pass (a folder replaced
        by its checkpoint) and the non-default style parameters of ``motion_filter_node``.

    Raises:
        ConfigurationError: an unknown preset, an unreadable style or personal model.
    """
    folder = model_path.get("model_path", "")
    if not style.strip() and not (folder and Path(folder).is_dir()):
        return dict(model_path), {}
    from audio2pose_ros.errors import InputError
    from audio2pose_ros.robot.description import load_robot
    from audio2pose_ros.style.figures import load_style
    from audio2pose_ros.style.personal import model_and_style, style_settings

    try:
        checkpoint, chosen = model_and_style(folder or None)
        if style.strip():
            chosen = load_style(style.strip())
        settings = style_settings(checkpoint, chosen, load_robot())
    except InputError as exc:
        raise ConfigurationError(f"launch argument style / model_path: {exc}") from None
    default = type(settings)()
    parameters = {
        name: getattr(settings, name)
        for name in settings.__dataclass_fields__
        if getattr(settings, name) != getattr(default, name)
    }
    return ({"model_path": str(checkpoint)} if folder else {}), parameters


@dataclass(frozen=True)
class LaunchPlan:
    """The launch file's arguments, validated and typed.

    Attributes:
        params_file: the parameters file of the three nodes.
        model_path: ``{"model_path": ...}`` to pass after the parameters file, or ``{}``.
        audio_ns: the audio topics' namespace (``""`` = root).
        controller_topic: where the filter's ``joint_trajectory_controller/joint_trajectory``
            output is remapped to.
        rviz: open RViz.
        robot_state_publisher: publish /robot_description and /tf from the commanded pose
            (only without a simulator: a simulated or real robot publishes its own).
        sim: ``"none"``, ``"gz"`` (gz sim with ros2_control) or ``"pybullet"``
            (``pepper_sim_node``: a simulated Pepper behind naoqi_driver's topics).
        diagnostic_aggregator: start diagnostic_aggregator with config/diagnostic_analyzers.yaml.
        single_process: run the three nodes in one process and one executor
            (:data:`SINGLE_PROCESS_MODULE`) instead of one process each.
        console: start console_node, the operator's web console (its settings come from the
            parameters file's ``console_node`` section).
        style: the motion filter's style parameters from the ``style`` argument (or a personal
            model's), passed after the parameters file; ``{}`` when none.
        voice_out: where voice_out_node sends the operator's voice (``off``: no voice node;
            ``topic``; ``naoqi:tcp://HOST:PORT``, checked by
            :func:`~audio2pose_ros.voice.naoqi.parse_voice_out`).

    """

    params_file: Path
    model_path: dict[str, str]
    audio_ns: str
    controller_topic: str
    rviz: bool
    robot_state_publisher: bool
    sim: str
    diagnostic_aggregator: bool
    single_process: bool = False
    console: bool = False
    style: dict[str, float] = field(default_factory=dict)
    voice_out: str = "off"

    @property
    def audio_topics(self) -> dict[str, str]:
        """Remappings of the features node's audio inputs."""
        # audio_capture's topics keep their names inside the chosen namespace
        return {name: topic_in(self.audio_ns, name.rsplit("/", 1)[-1]) for name in AUDIO_INPUTS}

    @property
    def commanded_state_publisher(self) -> bool:
        """robot_state_publisher on ``commanded_joint_states``: visualisation without a robot."""
        return self.robot_state_publisher and self.sim == "none"


def plan_launch(arguments: Mapping[str, str]) -> LaunchPlan:
    """Validate the launch file's arguments (strings, as launch hands them over).

    Args:
        arguments: a value for each of :data:`ARGUMENTS`.

    Returns:
        The plan the launch file builds its actions from.

    Raises:
        ConfigurationError: the first argument that is unusable, in one line.

    """
    sim = arguments["sim"].strip().lower()
    if sim not in SIM_CHOICES:
        raise ConfigurationError(
            f"launch argument sim:={arguments['sim']!r} is not one of {', '.join(SIM_CHOICES)}"
        )
    model_path, style = style_parameters(
        arguments["style"], model_path_override(arguments["model_path"])
    )
    return LaunchPlan(
        params_file=check_params_file(arguments["params_file"]),
        model_path=model_path,
        style=style,
        audio_ns=normalize_namespace("audio_ns", arguments["audio_ns"]),
        controller_topic=normalize_topic("controller_topic", arguments["controller_topic"]),
        rviz=parse_bool("rviz", arguments["rviz"]),
        robot_state_publisher=parse_bool(
            "robot_state_publisher", arguments["robot_state_publisher"]
        ),
        sim=sim,
        diagnostic_aggregator=parse_bool(
            "diagnostic_aggregator", arguments["diagnostic_aggregator"]
        ),
        single_process=parse_bool("single_process", arguments["single_process"]),
        console=parse_bool("console", arguments["console"]),
        voice_out=parse_voice_out(arguments["voice_out"]).describe(),
    )


def single_process_arguments(plan: LaunchPlan, directory: Path) -> list[str]:
    """``--ros-args`` of the single-process node executable for ``plan``.

    The same parameters and remappings the launch file gives the three nodes: the parameters
    file, then ``model_path`` for the two nodes that read it (written to a parameters file in
    ``directory`` that names each node, so it wins over the file's node sections as the
    per-node launch parameters do), the audio topics and the controller topic. In one process a
    remapping applies to every node; each of these names belongs to one node only.
    """
    arguments = ["--ros-args", "--params-file", str(plan.params_file)]
    if plan.model_path or plan.style:
        override = directory / "single_process_model_path.yaml"
        document: dict[str, object] = {
            node: {"ros__parameters": dict(plan.model_path)}
            for node in ("audio_features_node", "inference_node")
            if plan.model_path
        }
        if plan.style:
            document["motion_filter_node"] = {"ros__parameters": dict(plan.style)}
        override.write_text(yaml.safe_dump(document), encoding="utf-8")
        arguments += ["--params-file", str(override)]
    remaps = {
        **plan.audio_topics,
        topics.JOINT_TRAJECTORY: plan.controller_topic,
    }
    for name, target in remaps.items():
        arguments += ["-r", f"{name}:={target}"]
    return arguments


def describe_exit(returncode: int) -> str:
    """``status 1`` or ``killed by SIGKILL`` (a negative return code is the signal)."""
    if returncode < 0:
        try:
            return f"killed by {signal.Signals(-returncode).name}"
        except ValueError:
            return f"killed by signal {-returncode}"
    return f"status {returncode}"


class GaveUpError(Audio2PoseError):
    """A node kept exiting: its restart budget is spent."""


@dataclass(frozen=True)
class RespawnDecision:
    """What to do about a node process that exited.

    Attributes:
        restart: start it again after ``delay_s``; False: stop the whole launch.
        delay_s: back-off before the restart (s).
        message: one line for the log (the reason to stop, when ``restart`` is False).
        configuration_error: the node exited with :data:`EXIT_CONFIGURATION_ERROR`.

    """

    restart: bool
    delay_s: float
    message: str
    configuration_error: bool = False

    def error(self) -> Audio2PoseError:
        """The exception that ends the launch when ``restart`` is False."""
        return (ConfigurationError if self.configuration_error else GaveUpError)(self.message)


@dataclass
class RespawnBudget:
    """Restart crashed nodes with exponential back-off, at most ``max_restarts`` in a row.

    The first restart in a row is immediate (a single crash should cost the robot only the
    node's start-up time); the k-th (k >= 2) waits ``first_delay_s * 2**(k-2)`` seconds, at
    most ``max_delay_s``; one more crash gives up. A process that ran ``healthy_after_s`` or
    longer before it exited starts a new row, so a node that crashes once an hour is always
    restarted at once, while a crash loop ends after ``max_restarts`` restarts whatever the
    delays and start-up times. Exit status :data:`EXIT_CONFIGURATION_ERROR` gives up at once:
    the same configuration would fail again.

    Attributes:
        max_restarts: restarts in a row allowed per node.
        healthy_after_s: a process that ran this long resets its node's row (s).
        first_delay_s: delay before the second restart in a row (s); the first has none.
        max_delay_s: cap of the back-off (s).

    """

    max_restarts: int = 5
    healthy_after_s: float = 30.0
    first_delay_s: float = 2.0
    max_delay_s: float = 8.0
    _in_a_row: dict[str, int] = field(default_factory=dict, repr=False)

    def forget(self) -> None:
        """Start every node's row afresh, as if each had run ``healthy_after_s``.

        For a caller that knows the exits so far were separate faults rather than a crash
        loop: the fault campaign kills nodes on purpose, one case after another.
        """
        self._in_a_row.clear()

    def on_exit(self, node: str, returncode: int, ran_s: float) -> RespawnDecision:
        """Decide about ``node`` whose process exited with ``returncode`` after ``ran_s`` s.

        Call it only for exits the launch did not ask for (not while shutting down).
        """
        how = describe_exit(returncode)
        if returncode == EXIT_CONFIGURATION_ERROR:
            return RespawnDecision(
                restart=False,
                delay_s=0.0,
                message=f"{node} cannot start with its configuration ({how}, see its error "
                "above): not restarting it; fix the parameters and launch again",
                configuration_error=True,
            )
        restarts = 0 if ran_s >= self.healthy_after_s else self._in_a_row.get(node, 0)
        if restarts >= self.max_restarts:
            return RespawnDecision(
                restart=False,
                delay_s=0.0,
                message=f"{node} exited ({how}) after {restarts} restarts in a row, each "
                f"running less than {self.healthy_after_s:g} s: giving up",
            )
        self._in_a_row[node] = restarts + 1
        delay_s = (
            0.0
            if restarts == 0
            else min(self.first_delay_s * 2 ** (restarts - 1), self.max_delay_s)
        )
        return RespawnDecision(
            restart=True,
            delay_s=delay_s,
            message=f"{node} exited ({how}) after {ran_s:.1f} s: restart {restarts + 1} of "
            f"{self.max_restarts} in a row, in {delay_s:g} s",
        )

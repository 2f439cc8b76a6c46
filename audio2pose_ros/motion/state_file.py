"""The motion filter's memory across restarts: last commanded pose, stop and enable.

A restarted ``motion_filter_node`` must not move the robot before it knows where the robot is,
and a stop must outlive the process that sent it (issue 11 item 5), as must ``enable: false``
(a restart must not bring back the motion an operator switched off). Without the robot's measured
joint states the node starts from the pose it last commanded, read from a small JSON file that
it rewrites atomically (a temporary file in the same directory, flushed, then renamed over the
old one) a few times per second and at every stop or release. A file that cannot be used is
reported and ignored; it never stops the node from starting.

The default location is ``$ROS_HOME/audio2pose_ros/`` (``~/.ros/audio2pose_ros/`` without
ROS_HOME), one file per node (by its fully qualified name).
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

from audio2pose_ros.errors import InputError
from audio2pose_ros.robot.description import RobotDescription

FORMAT_VERSION = 1
MAX_FILE_BYTES = 65536  # a state file is a few hundred bytes; anything larger is not ours


@dataclass(frozen=True)
class FilterMemory:
    """What a restarted filter needs to know.

    Attributes:
        joint_names: the joints of ``position_rad``, in the robot description's order.
        position_rad: the last commanded pose.
        stopped: a stop was in force.
        saved_at_s: wall-clock time of saving (s since the epoch).
        enabled: generated motion was enabled (files written before this field: True).
    """

    joint_names: tuple[str, ...]
    position_rad: tuple[float, ...]
    stopped: bool
    saved_at_s: float
    enabled: bool = True


def default_state_path(node_name: str) -> Path:
    """``$ROS_HOME/audio2pose_ros/<node>.json`` (ROS_HOME defaults to ``~/.ros``)."""
    ros_home = os.environ.get("ROS_HOME") or str(Path.home() / ".ros")
    safe = node_name.strip("/").replace("/", "__") or "motion_filter_node"
    return Path(ros_home) / "audio2pose_ros" / f"{safe}.json"


def save_memory(path: Path, memory: FilterMemory) -> None:
    """Write ``memory`` to ``path`` atomically (readers see the old or the new file, whole).

    Raises:
        OSError: the directory cannot be created or written.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps(
        {
            "format": FORMAT_VERSION,
            "joint_names": list(memory.joint_names),
            "position_rad": list(memory.position_rad),
            "stopped": memory.stopped,
            "enabled": memory.enabled,
            "saved_at_s": memory.saved_at_s,
        }
    )
    handle, temporary = tempfile.mkstemp(prefix=path.name, suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(handle, "w", encoding="utf-8") as stream:
            stream.write(text)
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


def load_memory(path: Path, robot: RobotDescription) -> FilterMemory | None:
    """The memory saved at ``path`` for ``robot``, or None when there is no file.

    Raises:
        InputError: the file cannot be read, is not a state file of this version, names other
            joints than ``robot`` or holds non-finite angles (the message names the file).
    """
    try:
        with path.open("rb") as stream:
            raw = stream.read(MAX_FILE_BYTES + 1)
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise InputError(f"{path}: cannot read the filter state: {exc}") from None
    if len(raw) > MAX_FILE_BYTES:
        raise InputError(f"{path}: larger than {MAX_FILE_BYTES} bytes, not a filter state file")
    try:
        data = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise InputError(f"{path}: not a JSON filter state: {exc}") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT_VERSION:
        raise InputError(f"{path}: not a filter state file of format {FORMAT_VERSION}")
    names, positions = data.get("joint_names"), data.get("position_rad")
    stopped, saved_at = data.get("stopped"), data.get("saved_at_s")
    if names != list(robot.names):
        raise InputError(f"{path}: joints {names} are not those of {robot.name}")
    if (
        not isinstance(positions, list)
        or len(positions) != robot.n_joints
        or not all(
            isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
            for v in positions
        )
    ):
        raise InputError(f"{path}: position_rad must be {robot.n_joints} finite angles")
    enabled = data.get("enabled", True)
    if (
        not isinstance(stopped, bool)
        or not isinstance(enabled, bool)
        or not isinstance(saved_at, int | float)
    ):
        raise InputError(
            f"{path}: 'stopped' and 'enabled' must be true/false and 'saved_at_s' a number"
        )
    return FilterMemory(
        tuple(names), tuple(float(v) for v in positions), stopped, float(saved_at), enabled
    )

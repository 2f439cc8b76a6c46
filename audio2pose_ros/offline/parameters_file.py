"""The nodes' parameter file read for offline use: offline motion is filtered like the robot's.

``audio2pose synth`` and ``audio2pose plot-filter`` build the online motion filter from the same
file ``motion_filter_node`` reads (``config/pepper.yaml`` by default, or the user's), so a
trajectory computed offline is the one the robot would be commanded. The file has the ROS 2
layout ``<node name or /**>: ros__parameters: {...}``; the node's own section wins over ``/**``,
as rcl resolves it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from audio2pose_ros.errors import Audio2PoseError, InputError
from audio2pose_ros.files import read_yaml_file
from audio2pose_ros.motion.filter import MotionFilter
from audio2pose_ros.motion.filter_settings import MotionFilterSettings
from audio2pose_ros.motion.limits import LimitSettings
from audio2pose_ros.parameters import settings_from
from audio2pose_ros.resources import share_path
from audio2pose_ros.robot.description import load_robot

FILTER_NODE = "motion_filter_node"  # the node whose section configures the motion filter


def _section(data: dict[str, Any], key: str, path: Path) -> dict[str, Any]:
    """``data[key]["ros__parameters"]``, checked to be a mapping (empty when absent)."""
    node = data.get(key)
    params = node.get("ros__parameters") if isinstance(node, dict) else None
    if node is not None and params is not None and not isinstance(params, dict):
        raise InputError(f"{path}: {key}.ros__parameters must be a mapping")
    return params or {}


def node_parameters(path: Path, node: str) -> dict[str, Any]:
    """The parameters ``node`` gets from the file at ``path``: ``/**`` overridden by its own.

    Raises:
        InputError: the file is unreadable, not YAML, or not laid out as a parameters file.
    """
    data = read_yaml_file(path, "parameters", InputError) or {}
    if not isinstance(data, dict):
        raise InputError(f"{path}: a parameters file is a mapping of node names")
    return {**_section(data, "/**", path), **_section(data, node, path)}


def motion_filter_from_file(path: Path | None = None) -> MotionFilter:
    """A MotionFilter configured as ``motion_filter_node`` is by the file (default: packaged).

    Raises:
        InputError: the file, its robot description or one of its values is refused.
    """
    path = path or share_path("config", "pepper.yaml")
    params = node_parameters(path, FILTER_NODE)
    robot_file = params.get("robot_description") or ""
    if not isinstance(robot_file, str):
        raise InputError(f"{path}: robot_description must be a string, got {robot_file!r:.40}")
    try:
        return MotionFilter(
            load_robot(robot_file or None),
            settings_from(MotionFilterSettings, params),
            settings_from(LimitSettings, params),
        )
    except Audio2PoseError as exc:
        raise InputError(f"{path}: {exc}") from None

"""A URDF's content as plain values, read by ``urdf_parser_py`` here or in a child process.

:mod:`~audio2pose_ros.robot.kinematics` checks and uses what ROS's own URDF parser
(``urdf_parser_py``) reads from a URDF: the robot's name, its links with their collision
shapes, its joints. :func:`outline` gives exactly that as dicts, lists, strings and numbers
(``None`` where the URDF leaves a value out).

The parser reads XML with ``lxml``: 4.2 MB of resident memory that stays mapped for the life of
a process once imported, while a node reads its URDF once, at start. The node processes
therefore call :func:`parse_apart` first thing (:mod:`audio2pose_ros.ros.nodes.process`): their
URDFs are then parsed by the same parser in a short-lived child process,
``python -m audio2pose_ros.robot.urdf_outline``, which reads the XML on stdin and prints the
outline, or the parser's complaint, as one JSON line. The values and the errors are the same
either way; the child takes about 0.1 s longer than a parse in process. Other processes (the
command line, the tests, the offline tools) parse in their own process.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

__all__ = ["UrdfParseError", "outline", "parse_apart", "read_outline"]

_settings = {"apart": False}


class UrdfParseError(Exception):
    """The parser refused the URDF; the message is the parser's exception, as ``repr``."""


def parse_apart(enabled: bool = True) -> None:
    """Make :func:`read_outline` parse in a child process (``enabled``) or in this one."""
    _settings["apart"] = enabled


def read_outline(urdf_xml: str) -> dict[str, Any]:
    """The outline of ``urdf_xml``, parsed where :func:`parse_apart` said.

    The child runs this interpreter on this module, this package first on its path. If it cannot
    be started at all (no interpreter to run), the URDF is parsed here.

    Raises:
        UrdfParseError: the parser refused the text, or the child process failed.
    """
    if not _settings["apart"]:
        return outline(urdf_xml)
    import os
    import subprocess  # here: the node processes import this module before anything else

    package_root = str(Path(__file__).resolve().parents[2])
    path = os.pathsep.join(p for p in (package_root, os.environ.get("PYTHONPATH")) if p)
    try:
        done = subprocess.run(
            [sys.executable, "-m", __name__],
            input=urdf_xml.encode("utf-8"),
            capture_output=True,
            check=False,
            env={**os.environ, "PYTHONPATH": path},
        )
    except OSError:
        return outline(urdf_xml)
    lines = done.stdout.decode("utf-8", "replace").strip().splitlines()
    try:
        answer = json.loads(lines[-1]) if done.returncode == 0 and lines else None
    except ValueError:
        answer = None
    if not isinstance(answer, dict) or not ({"outline", "error"} & answer.keys()):
        stderr = done.stderr.decode("utf-8", "replace").strip()[-500:]
        raise UrdfParseError(f"the URDF parser process failed (exit {done.returncode}): {stderr}")
    if "error" in answer:
        raise UrdfParseError(str(answer["error"]))
    return dict(answer["outline"])


def outline(urdf_xml: str) -> dict[str, Any]:
    """Parse ``urdf_xml`` with ``urdf_parser_py`` in this process; its outline.

    Tags the parser does not know (``<ros2_control>``, ``<gazebo>``) are skipped, as ROS does;
    the parser's complaints are not printed.

    Raises:
        UrdfParseError: the parser refused the text.
    """
    from urdf_parser_py import xml_reflection
    from urdf_parser_py.urdf import URDF

    previous = xml_reflection.core.on_error
    xml_reflection.core.on_error = lambda _complaint: None
    try:
        robot = URDF.from_xml_string(urdf_xml.encode("utf-8"))
    except Exception as exc:  # lxml's syntax errors, the parser's own (KeyError, AssertionError)
        raise UrdfParseError(repr(exc)) from None
    finally:
        xml_reflection.core.on_error = previous
    return {
        "name": robot.name,
        "links": [
            {"name": link.name, "collisions": [_collision(c) for c in link.collisions]}
            for link in robot.links
        ],
        "joints": [_joint(joint) for joint in robot.joints],
    }


def _pose(pose: Any) -> dict[str, Any] | None:
    return None if pose is None else {"xyz": pose.xyz, "rpy": pose.rpy}


def _joint(joint: Any) -> dict[str, Any]:
    limit = joint.limit
    return {
        "name": joint.name,
        "type": joint.type,
        "parent": joint.parent,
        "child": joint.child,
        "axis": joint.axis,
        "limit": None
        if limit is None
        else {"lower": limit.lower, "upper": limit.upper, "velocity": limit.velocity},
        "origin": _pose(joint.origin),
    }


def _collision(collision: Any) -> dict[str, Any]:
    geometry = collision.geometry
    return {
        "geometry": None
        if geometry is None
        else {
            "kind": type(geometry).__name__.lower(),
            **{key: getattr(geometry, key, None) for key in ("size", "radius", "length")},
        },
        "origin": _pose(collision.origin),
    }


def main() -> None:
    """The child process: a URDF on stdin, one JSON line on stdout (its outline or error)."""
    text = sys.stdin.buffer.read().decode("utf-8", "replace")
    try:
        answer: dict[str, Any] = {"outline": outline(text)}
    except UrdfParseError as exc:
        answer = {"error": str(exc)}
    sys.stdout.write(json.dumps(answer, default=repr) + "\n")


if __name__ == "__main__":
    main()

"""What the page shows of the operator's voice out of the robot: mute, latencies, offset.

``voice_out_node`` reports on /diagnostics the three parts of the latency it holds the voice
back by (``graph_latency``, ``execution_latency``, ``loudspeaker_latency``, each as
``85 ms (measured, 12)`` or ``100 ms (default: not measured)``), the delay applied
(``voice_delay_ms``), the resulting ``motion - heard`` offset (``offset_ms``) and whether the
voice is ``muted``. :func:`voice_view` turns those values into the ``voice`` field of the
console's status, with why a part uses its default: the node's own note where it gives one
(``graph_latency_note``, as "not measured: <note>"), otherwise what the console sees of the
robot (its measured joint states, its microphones). This module does not import rclpy.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass

from audio2pose_ros.voice.sync import WINDOW_EARLY_S, WINDOW_LATE_S

__all__ = ["PARTS", "VOICE_KEYS", "RobotSeen", "part_view", "voice_view"]

PARTS = ("graph", "execution", "loudspeaker")
# The voice node's /diagnostics values the console keeps (every other key is ignored).
VOICE_KEYS = frozenset(
    {
        "voice_out",
        "muted",
        "voice_delay_ms",
        "offset_ms",
        *(f"{part}_latency" for part in PARTS),
        *(f"{part}_latency_note" for part in PARTS),
    }
)
_PART = re.compile(r"^\s*(-?\d+(?:\.\d+)?)\s*ms\s*\((measured|default)\b")
_NUMBER = re.compile(r"^\s*([-+]?\d+(?:\.\d+)?)\s*$")


@dataclass(frozen=True)
class RobotSeen:
    """What the console itself receives of the robot now.

    Attributes:
        joint_states: measured joint states arrive (a robot or the simulator reports its pose).
        microphones: the robot's microphones arrive (naoqi_driver's ``audio``).
        talked: the operator's voice has reached the graph since the console started.
    """

    joint_states: bool
    microphones: bool
    talked: bool


def _why_default(part: str, seen: RobotSeen) -> str:
    """Why ``part`` is not measured, from what the console receives of the robot."""
    if part == "execution" and not seen.joint_states:
        return "not measurable: the robot reports no measured joint_states"
    if part == "loudspeaker" and not seen.microphones:
        return "not measurable: no robot microphones on audio"
    if not seen.talked:
        return "not measured yet: talk for a few seconds"
    return {
        "graph": "not measured yet: needs raw_trajectory and commanded_joint_states while you talk",
        "execution": "not measured yet: needs the robot's measured motion while you talk",
        "loudspeaker": "not measured yet: the robot's microphones have not heard the voice",
    }[part]


def part_view(part: str, values: Mapping[str, str], seen: RobotSeen) -> dict[str, object]:
    """One latency part: ``{"ms": 85.0, "measured": True, "why": "", "text": ...}``.

    ``ms`` is None where the node's value cannot be read (then ``why`` says so).
    """
    text = values.get(f"{part}_latency", "")
    match = _PART.match(text)
    if match is None:
        why = f"not reported by the voice node ({text or 'no value'})"
        return {"ms": None, "measured": False, "why": why, "text": text}
    measured = match.group(2) == "measured"
    why = ""
    if not measured:
        note = values.get(f"{part}_latency_note", "")
        why = f"not measured: {note}" if note else _why_default(part, seen)
    return {"ms": float(match.group(1)), "measured": measured, "why": why, "text": text}


def _number(text: str | None) -> float | None:
    match = _NUMBER.match(text or "")
    return float(match.group(1)) if match else None


def voice_view(
    values: Mapping[str, str] | None,
    muted: bool | None,
    seen: RobotSeen,
    problem: str,
    age_s: float = 0.0,
) -> dict[str, object]:
    """The status's ``voice`` field.

    Args:
        values: the voice node's last /diagnostics values (None: no voice node heard).
        muted: its ``muted`` parameter as last read back (None: not read).
        seen: what the console receives of the robot.
        problem: why the last mute could not be set ('' when none).
        age_s: how long ago ``values`` were reported (s).

    Returns:
        ``available`` (a voice node reports), ``muted``, ``destination``, ``parts`` (graph,
        execution, loudspeaker: :func:`part_view`), ``delay_ms``, ``offset_ms`` and the window
        ``[early_ms, late_ms]`` the offset should stay in, ``problem``, ``reported_s_ago``
        (None without values).
    """
    values = values or {}
    if muted is None and "muted" in values:
        muted = values["muted"].strip().lower() == "true"
    return {
        "available": bool(values),
        "muted": muted,
        "destination": values.get("voice_out", ""),
        "parts": {part: part_view(part, values, seen) for part in PARTS} if values else {},
        "delay_ms": _number(values.get("voice_delay_ms")),
        "offset_ms": _number(values.get("offset_ms")),
        "window_ms": [-WINDOW_EARLY_S * 1e3, WINDOW_LATE_S * 1e3],
        "problem": problem,
        "reported_s_ago": round(age_s, 1) if values else None,
    }

"""The QoS profiles the graph's topics use, defined once for the nodes, tools and tests."""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

# Audio: best effort matches both reliable and best-effort publishers (audio_capture is reliable);
# a deep queue absorbs bursts from GStreamer without dropping chunks.
AUDIO_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.BEST_EFFORT
)
# AudioInfo is latched (transient local) by audio_capture and republished every 5 s.
LATCHED_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
# Between our own nodes: reliable, so no feature frame or pose is lost silently.
STREAM_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE
)


def is_best_effort_volatile(qos: QoSProfile | int) -> bool:
    """Whether ``qos`` is a best-effort, volatile profile (every publisher is compatible)."""
    return (
        isinstance(qos, QoSProfile)
        and qos.reliability == ReliabilityPolicy.BEST_EFFORT
        and qos.durability != DurabilityPolicy.TRANSIENT_LOCAL
    )

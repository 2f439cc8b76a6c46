"""The QoS profiles the graph's topics use, defined once, and the check of a topic's publishers.

The nodes create no QoS event handlers (rclpy's default ones are polled in Python at every wait
of the SingleThreadedExecutor: half the cost of an idle round of the motion filter). A publisher
whose QoS a node's reader cannot match (a best-effort ``stop``) is found from the graph instead
(:func:`incompatible_publishers`, with rclpy's own ``qos_check_compatible``), on every distro.
"""

from __future__ import annotations

from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSCompatibility,
    QoSProfile,
    ReliabilityPolicy,
    qos_check_compatible,
)

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
# The motion filter's reader of raw poses: best effort, which matches the reliable publishers
# (STREAM_QOS). A node's inputs share its DDS participant's receive path: a flood on another
# input (/joint_states, stop: false) loses a raw pose there now and then. A reliable reader
# repairs it only a heartbeat round later (0.4-0.9 s measured) and, delivering in order, holds
# every later pose behind it: the commands glided to neutral and replayed the backlog, 0.5 rad
# off their track. A pose that late is of no use to a 100 Hz track: best effort loses the one
# pose (the filter bridges it; counted by sequence numbers where rclpy gives them) and delivers
# the next on time.
RAW_POSE_READER_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.BEST_EFFORT
)


def is_best_effort_volatile(qos: QoSProfile) -> bool:
    """Whether ``qos`` is a best-effort, volatile profile (every publisher is compatible)."""
    return (
        qos.reliability == ReliabilityPolicy.BEST_EFFORT
        and qos.durability != DurabilityPolicy.TRANSIENT_LOCAL
    )


def incompatible_publishers(node: Node, topic: str, reader: QoSProfile) -> list[str]:
    """The publishers of ``topic`` (fully qualified) whose QoS ``reader`` cannot match.

    Each as ``"<node> (<reason>)"``: their messages never reach the reader.
    """
    found = []
    for info in node.get_publishers_info_by_topic(topic):
        compatibility, reason = qos_check_compatible(info.qos_profile, reader)
        if compatibility == QoSCompatibility.ERROR:
            name = f"{info.node_namespace.rstrip('/')}/{info.node_name}"
            found.append(f"{name} ({reason.strip()})")
    return found

"""The one player: publishes recorded or synthesised messages into a live graph with their timing.

``audio2pose bag replay``, ``audio2pose run --play``, the graph benchmark and the launch tests
all publish audio through :class:`MessagePlayer`. Messages are
:class:`~audio2pose_ros.data.bag.BagMessage` (topic, type name, CDR bytes, time stamp); the
player publishes the serialised bytes as they are, so what a bag holds is exactly what the graph
receives. Each topic gets the QoS a live source offers (:func:`replay_qos`): ``audio_info``
latched as audio_capture publishes it, everything else reliable with a deep queue.

Only message types in :data:`~audio2pose_ros.data.bag.KNOWN_MESSAGE_TYPES` get a publisher
(:func:`message_class`): a bag cannot make this process import anything else.
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

import rclpy
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from audio2pose_ros.data.bag import (
    AUDIO_DATA_TYPE,
    AUDIO_INFO_TYPE,
    KNOWN_MESSAGE_TYPES,
    BagError,
    BagMessage,
    check_known_type,
)
from audio2pose_ros.ros.executor import shutdown
from audio2pose_ros.timebase import SAMPLES_PER_FRAME

STREAM_DEPTH = 100  # queue depth of replayed streams: absorbs bursts like the graph's own streams
SPIN_PERIOD_S = 0.005  # longest wait between two looks at the callbacks while waiting
ACK_TIMEOUT_S = 5.0  # how long a replay waits for its subscribers to acknowledge the last messages


def message_class(msgtype: str) -> type:
    """The rclpy message class of a known type name such as ``sensor_msgs/msg/JointState``.

    Raises:
        BagError: the type is not a known one, or its package is not installed here.
    """
    check_known_type(msgtype, "bag")
    try:
        module = importlib.import_module(KNOWN_MESSAGE_TYPES[msgtype])
        return getattr(module, msgtype.split("/")[-1])
    except (ImportError, AttributeError):
        raise BagError(f"message type {msgtype} is not available here") from None


def replay_qos(msgtype: str) -> QoSProfile:
    """The QoS a live publisher of ``msgtype`` offers: AudioInfo latched, the rest reliable."""
    latched = msgtype == AUDIO_INFO_TYPE
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=1 if latched else STREAM_DEPTH,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )


@contextmanager
def rclpy_session(args: list[str] | None = None) -> Iterator[None]:
    """Rclpy initialised (with ``args``) for the ``with`` block and shut down after it.

    For the processes that play into a graph (the runner, the bench, bag replay) and the tests:
    ``with rclpy.init()`` is not available on Humble nor Jazzy, whose ``init`` returns nothing.
    """
    rclpy.init(args=args)
    try:
        yield
    finally:
        shutdown()


def spin_until(node: Node, deadline_s: float, done: Callable[[], bool] | None = None) -> bool:
    """Process ``node``'s callbacks until ``deadline_s`` (monotonic) or until ``done()`` is true.

    Returns:
        Whether ``done()`` became true (True without ``done`` once the deadline is reached).
    """
    while (wait := deadline_s - time.monotonic()) > 0:
        rclpy.spin_once(node, timeout_sec=min(wait, SPIN_PERIOD_S))
        if done is not None and done():
            return True
    return done is None


class MessagePlayer:
    """Publishers for a set of (topic, type) pairs on ``node``, and the timing loop."""

    def __init__(self, node: Node, topics: Iterable[tuple[str, str]]) -> None:
        """One publisher per (topic, message type name), with :func:`replay_qos`."""
        self.node = node
        self.publishers: dict[str, Publisher[Any]] = {
            topic: node.create_publisher(message_class(msgtype), topic, replay_qos(msgtype))
            for topic, msgtype in dict(topics).items()
        }

    def publish(self, message: BagMessage) -> None:
        """Publish one message's serialised bytes on its topic."""
        self.publishers[message.topic].publish(message.data)

    def delivered(self, timeout_s: float) -> bool:
        """Wait until every reliable subscriber acknowledged every message, at most ``timeout_s``.

        A process that destroys its publishers right after the last ``publish`` can take
        messages still in flight with it; waiting for the acknowledgements first does not.
        Best-effort subscribers send none and are not waited for.
        """
        deadline = time.monotonic() + timeout_s
        return all(
            publisher.wait_for_all_acked(
                Duration(nanoseconds=max(0, int((deadline - time.monotonic()) * 1e9)))
            )
            for publisher in self.publishers.values()
        )

    def wait_for_subscribers(self, timeout_s: float) -> bool:
        """Spin until every topic has a subscriber, for at most ``timeout_s``."""
        return spin_until(
            self.node,
            time.monotonic() + timeout_s,
            lambda: all(p.get_subscription_count() for p in self.publishers.values()),
        )

    def play(
        self,
        messages: Sequence[BagMessage],
        rate: float = 1.0,
        on_publish: Callable[[BagMessage], None] | None = None,
    ) -> float:
        """Publish ``messages`` at their time stamps (relative to the first), ``rate`` x faster.

        The node's callbacks are processed while waiting. ``on_publish`` is called right after
        each message is published (the benchmark stamps its send times there).

        Returns:
            The monotonic time at which the first message was due.
        """
        start = time.monotonic()
        first_ns = messages[0].timestamp_ns if messages else 0
        for message in messages:
            spin_until(self.node, start + (message.timestamp_ns - first_ns) * 1e-9 / rate)
            self.publish(message)
            if on_publish is not None:
                on_publish(message)
        return start


def replay_bag(
    messages: Sequence[BagMessage], rate: float, wait_s: float, ack_timeout_s: float = ACK_TIMEOUT_S
) -> tuple[int, float, bool]:
    """Publish checked bag messages with their recorded timing in a node of their own.

    Waits up to ``wait_s`` for a subscriber on every topic first, then plays ``rate`` x faster,
    then up to ``ack_timeout_s`` for the subscribers to acknowledge every message
    (:meth:`MessagePlayer.delivered`) before the node goes.

    Returns:
        The number of topics published, the seconds the playback took, and whether every
        message was acknowledged.
    """
    with rclpy_session():
        node = rclpy.create_node("audio2pose_bag_replay")
        player = MessagePlayer(node, ((m.topic, m.msgtype) for m in messages))
        player.wait_for_subscribers(wait_s)
        start = player.play(messages, rate)
        elapsed_s = time.monotonic() - start
        acknowledged = player.delivered(ack_timeout_s)
        node.destroy_node()
    return len(player.publishers), elapsed_s, acknowledged


def silence_message(topic: str, frames: int = 1) -> BagMessage:
    """An AudioData message of ``frames`` whole frames of 16-bit silence.

    Whole frames keep a streaming feature extractor aligned to the frame grid while a player
    warms the graph up.
    """
    from audio_common_msgs.msg import AudioData
    from rclpy.serialization import serialize_message

    data = serialize_message(AudioData(data=bytes(2 * SAMPLES_PER_FRAME * frames)))
    return BagMessage(topic=topic, msgtype=AUDIO_DATA_TYPE, data=data, timestamp_ns=0)


def warm_up(
    player: MessagePlayer, audio_topic: str, answered: Callable[[], bool], timeout_s: float
) -> bool:
    """Send one frame of silence every 20 ms until ``answered()``: every link has matched.

    DDS discovery is asymmetric: a node may see our subscription before its own publisher has
    matched the next node, and reliable volatile samples sent before that are lost, so a
    player waits for the graph's answer rather than for its own subscribers.

    Returns:
        Whether the graph answered within ``timeout_s``.
    """
    silence = silence_message(audio_topic)

    def sent_and_answered() -> bool:
        player.publish(silence)
        spin_until(player.node, time.monotonic() + 0.02)
        return answered()

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if sent_and_answered():
            return True
    return False

"""``audio2pose bag``: make speech bags from WAV files and replay bags into a running graph.

``bag replay`` publishes only the message types this project knows
(:data:`audio2pose_ros.data.bag.KNOWN_MESSAGE_TYPES`), after checking every message's CDR bytes, and
with the QoS a live source offers: ``audio_info`` latched (reliable, transient local, as
audio_capture publishes it and audio_features_node subscribes to it), everything else reliable
and volatile with a deep queue, so a replayed bag drives the real graph as a microphone does.
"""

from __future__ import annotations

import argparse
import importlib
import time

from audio2pose_ros.cli.options import (
    MAX_SEED,
    bounded_float,
    bounded_int,
    input_bag,
    input_file,
    new_dir,
)
from audio2pose_ros.data.bag import (
    AUDIO_INFO_TYPE,
    KNOWN_MESSAGE_TYPES,
    MAX_CHUNK_BYTES,
    BagError,
    Chunking,
    check_known_type,
    read_checked_messages,
    write_audio_bag,
)
from audio2pose_ros.errors import UsageError

MAX_REPLAY_RATE = 100.0  # --rate: at most 100x the recorded speed
MAX_WAIT_S = 3600.0
MAX_REPLAY_S = 24 * 3600.0  # a bag whose timestamps span more than a day is refused
STREAM_DEPTH = 100  # replay queue depth: absorbs bursts like the graph's own streams


def message_class(msgtype: str) -> type:
    """The rclpy message class of a known type name such as ``sensor_msgs/msg/JointState``.

    Only types in :data:`~audio2pose_ros.data.bag.KNOWN_MESSAGE_TYPES` are imported, from the module
    that table names; a bag cannot make this process import anything else.

    Raises:
        BagError: the type is not a known one, or its package is not installed here.
    """
    check_known_type(msgtype, "bag")
    module = KNOWN_MESSAGE_TYPES[msgtype]
    try:
        return getattr(importlib.import_module(module), msgtype.rsplit("/", 1)[1])
    except (ImportError, AttributeError):
        raise BagError(f"message type {msgtype} is not available in this environment") from None


def replay_qos(msgtype: str):  # noqa: ANN201 - rclpy imported lazily
    """The QoS a live publisher of ``msgtype`` offers: AudioInfo latched, the rest reliable."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    latched = msgtype == AUDIO_INFO_TYPE
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=1 if latched else STREAM_DEPTH,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )


def command_from_wav(args: argparse.Namespace) -> int:
    """Write a WAV's audio as AudioData + AudioInfo chunks, as a live capture delivers them."""
    from audio2pose_ros.audio.pcm import read_wav

    if args.min_bytes > args.max_bytes:
        raise UsageError(
            f"--min-bytes {args.min_bytes} is larger than --max-bytes {args.max_bytes}"
        )
    output = new_dir(args.output, "-o")
    signal, _ = read_wav(input_file(args.wav, "WAV file"))
    chunking = Chunking(min_bytes=args.min_bytes, max_bytes=args.max_bytes, seed=args.seed)
    count = write_audio_bag(signal, output, chunking, storage=args.storage)
    print(f"wrote {count} AudioData messages ({len(signal) / 16000:.2f} s) to {output}")
    return 0


def command_replay(args: argparse.Namespace) -> int:
    """Publish every message of a bag with its recorded timing, ``--rate`` times faster.

    Every message is checked (known type, valid CDR) before the first one is published, and
    a bag whose replay would last more than :data:`MAX_REPLAY_S` is refused.
    """
    import rclpy

    bag = input_bag(args.bag)
    messages = read_checked_messages(bag, args.topics or None)
    if not messages:
        raise BagError(f"{bag}: no messages of a known type to replay")
    span_s = (messages[-1].timestamp_ns - messages[0].timestamp_ns) * 1e-9 / args.rate
    if span_s > MAX_REPLAY_S:
        raise BagError(
            f"{bag}: replaying would take {span_s:.3g} s at --rate {args.rate:g}; at most "
            f"{MAX_REPLAY_S:g} s (check the bag's timestamps)"
        )
    with rclpy.init():
        node = rclpy.create_node("audio2pose_bag_replay")
        publishers = {
            m.topic: node.create_publisher(message_class(m.msgtype), m.topic, replay_qos(m.msgtype))
            for m in messages
        }
        deadline = time.monotonic() + args.wait_s
        while time.monotonic() < deadline and not all(
            p.get_subscription_count() for p in publishers.values()
        ):
            rclpy.spin_once(node, timeout_sec=0.05)
        start_ns, start = messages[0].timestamp_ns, time.monotonic()
        for message in messages:
            due = start + (message.timestamp_ns - start_ns) * 1e-9 / args.rate
            while (wait := due - time.monotonic()) > 0:
                rclpy.spin_once(node, timeout_sec=min(wait, 0.01))
            publishers[message.topic].publish(message.data)
        node.destroy_node()
    print(
        f"replayed {len(messages)} messages on {len(publishers)} topics in "
        f"{time.monotonic() - start:.2f} s"
    )
    return 0


def register(verbs: argparse._SubParsersAction) -> None:
    """Add ``audio2pose bag from-wav`` and ``audio2pose bag replay``."""
    bag = verbs.add_parser("bag", help="speech bags: make from WAV, replay")
    sub = bag.add_subparsers(dest="bag_verb", required=True)
    chunk_bytes = bounded_int(1, MAX_CHUNK_BYTES)

    from_wav = sub.add_parser("from-wav", help="WAV -> rosbag2 of AudioData + AudioInfo")
    from_wav.add_argument("wav", metavar="FILE.wav")
    from_wav.add_argument("-o", "--output", required=True, metavar="BAG")
    from_wav.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
    from_wav.add_argument(
        "--min-bytes",
        type=chunk_bytes,
        default=Chunking.min_bytes,
        help=f"smallest AudioData payload, 1 to {MAX_CHUNK_BYTES} (default %(default)s)",
    )
    from_wav.add_argument(
        "--max-bytes",
        type=chunk_bytes,
        default=Chunking.max_bytes,
        help=f"largest AudioData payload, 1 to {MAX_CHUNK_BYTES} (default %(default)s)",
    )
    from_wav.add_argument("--seed", type=bounded_int(0, MAX_SEED), default=0)
    from_wav.set_defaults(func=command_from_wav)

    replay = sub.add_parser("replay", help="publish a bag with its original timing (or faster)")
    replay.add_argument("bag", metavar="BAG")
    replay.add_argument(
        "--rate",
        type=bounded_float(0.0, MAX_REPLAY_RATE, low_inclusive=False),
        default=1.0,
        help=f"speed factor in (0, {MAX_REPLAY_RATE:g}] (default 1)",
    )
    replay.add_argument("--topics", nargs="*", help="only these topics")
    replay.add_argument(
        "--wait-s",
        type=bounded_float(0.0, MAX_WAIT_S),
        default=10.0,
        help="wait this long for subscribers before starting (default 10)",
    )
    replay.set_defaults(func=command_replay)

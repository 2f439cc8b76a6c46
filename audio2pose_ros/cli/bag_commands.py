"""``audio2pose bag``: make speech bags from WAV files and replay bags into a running graph."""

from __future__ import annotations

import argparse
import importlib
import time
from pathlib import Path

from audio2pose_ros.bag import BagError, Chunking, read_messages, write_audio_bag


def message_class(msgtype: str) -> type:
    """The rclpy message class for a type name such as ``sensor_msgs/msg/JointState``.

    Raises:
        BagError: the type's package is not importable here.
    """
    package, kind, name = msgtype.split("/")
    try:
        return getattr(importlib.import_module(f"{package}.{kind}"), name)
    except (ImportError, AttributeError):
        raise BagError(f"message type {msgtype} is not available in this environment") from None


def command_from_wav(args: argparse.Namespace) -> int:
    """Write a WAV's audio as AudioData + AudioInfo chunks, as a live capture delivers them."""
    from audio2pose_ros.audio.pcm import read_wav

    if Path(args.output).exists():
        raise ValueError(f"{args.output} exists already; rosbag2 output must be a new directory")
    signal, _ = read_wav(args.wav)
    chunking = Chunking(min_bytes=args.min_bytes, max_bytes=args.max_bytes, seed=args.seed)
    count = write_audio_bag(signal, args.output, chunking, storage=args.storage)
    print(f"wrote {count} AudioData messages ({len(signal) / 16000:.2f} s) to {args.output}")
    return 0


def command_replay(args: argparse.Namespace) -> int:
    """Publish every message of a bag with its recorded timing, ``--rate`` times faster."""
    import rclpy

    if args.rate <= 0:
        raise ValueError(f"--rate must be positive, got {args.rate}")
    messages = list(read_messages(args.bag, args.topics or None))
    if not messages:
        raise BagError(f"{args.bag}: no messages to replay")
    with rclpy.init():
        node = rclpy.create_node("audio2pose_bag_replay")
        publishers = {
            m.topic: node.create_publisher(message_class(m.msgtype), m.topic, 100) for m in messages
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

    from_wav = sub.add_parser("from-wav", help="WAV -> rosbag2 of AudioData + AudioInfo")
    from_wav.add_argument("wav", metavar="FILE.wav")
    from_wav.add_argument("-o", "--output", required=True, metavar="BAG")
    from_wav.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
    from_wav.add_argument("--min-bytes", type=int, default=Chunking.min_bytes)
    from_wav.add_argument("--max-bytes", type=int, default=Chunking.max_bytes)
    from_wav.add_argument("--seed", type=int, default=0)
    from_wav.set_defaults(func=command_from_wav)

    replay = sub.add_parser("replay", help="publish a bag with its original timing (or faster)")
    replay.add_argument("bag", metavar="BAG")
    replay.add_argument("--rate", type=float, default=1.0, help="speed factor (default 1)")
    replay.add_argument("--topics", nargs="*", help="only these topics")
    replay.add_argument(
        "--wait-s",
        type=float,
        default=10.0,
        help="wait this long for subscribers before starting (default 10)",
    )
    replay.set_defaults(func=command_replay)

"""``audio2pose bag``: make speech bags from WAV files and replay bags into a running graph.

``bag replay`` checks every message's type and CDR bytes
(:func:`~audio2pose_ros.data.bag.read_checked_messages`) and hands them to
:func:`audio2pose_ros.ros.player.replay_bag`, which publishes them with their recorded timing and
the QoS a live source offers, so a replayed bag drives the real graph as a microphone does.
"""

from __future__ import annotations

import argparse
import sys

from audio2pose_ros.cli.options import (
    MAX_SEED,
    Verbs,
    bag_inputs,
    bounded_float,
    bounded_int,
    check_apart,
    input_bag,
    input_file,
    new_dir,
)
from audio2pose_ros.data.bag import (
    KNOWN_MESSAGE_TYPES,
    MAX_CHUNK_BYTES,
    BagError,
    Chunking,
    bag_topics,
    read_checked_messages,
    repair_bag,
    select_for_replay,
    write_audio_bag,
)
from audio2pose_ros.errors import UsageError
from audio2pose_ros.timebase import duration_s

MAX_REPLAY_RATE = 100.0  # --rate: at most 100x the recorded speed
MAX_WAIT_S = 3600.0
MAX_REPLAY_S = 24 * 3600.0  # a bag whose timestamps span more than a day is refused


def command_from_wav(args: argparse.Namespace) -> int:
    """Write a WAV's audio as AudioData + AudioInfo chunks, as a live capture delivers them."""
    from audio2pose_ros.audio.wav import read_wav

    if args.min_bytes > args.max_bytes:
        raise UsageError(
            f"--min-bytes {args.min_bytes} is larger than --max-bytes {args.max_bytes}"
        )
    output = new_dir(args.output, "-o")
    signal, _ = read_wav(input_file(args.wav, "WAV file"))
    chunking = Chunking(min_bytes=args.min_bytes, max_bytes=args.max_bytes, seed=args.seed)
    count = write_audio_bag(signal, output, chunking, storage=args.storage)
    print(f"wrote {count} AudioData messages ({duration_s(len(signal)):.2f} s) to {output}")
    return 0


def command_replay(args: argparse.Namespace) -> int:
    """Publish a bag's audio (or the named topics) with its recorded timing, ``--rate`` faster.

    Every message is checked (known type, valid CDR) before the first one is published, and
    a bag whose replay would last more than :data:`MAX_REPLAY_S` is refused. Exits 1 with a
    warning when a subscriber has not acknowledged every message soon after the last one.
    """
    from audio2pose_ros.ros.player import ACK_TIMEOUT_S, replay_bag

    bag = input_bag(args.bag)
    selection = select_for_replay(
        read_checked_messages(bag, args.topics or None), bool(args.topics)
    )
    if selection.left_out:
        print(
            f"not replayed: {', '.join(selection.left_out)} (robot commands or the graph's own "
            "topics; name them with --topics to replay them)",
            file=sys.stderr,
        )
    if selection.commanding:
        print(
            f"warning: replaying {', '.join(selection.commanding)}: these topics command the "
            "robot or stand in for the graph's own nodes, past the motion filter's input checks; "
            "stop the graph (or the robot's driver) first unless you mean it",
            file=sys.stderr,
        )
    messages = selection.messages
    if not messages:
        found = ", ".join(
            f"{topic} ({msgtype}{'' if msgtype in KNOWN_MESSAGE_TYPES else ', not a known type'})"
            for topic, msgtype in sorted(bag_topics(bag).items())
        )
        raise BagError(
            f"{bag}: no audio to replay (it holds: {found or 'no topics'}; name known topics "
            "with --topics)"
        )
    span_s = (messages[-1].timestamp_ns - messages[0].timestamp_ns) * 1e-9 / args.rate
    if span_s > MAX_REPLAY_S:
        raise BagError(
            f"{bag}: replaying would take {span_s:.3g} s at --rate {args.rate:g}; at most "
            f"{MAX_REPLAY_S:g} s (check the bag's timestamps)"
        )
    topics, elapsed_s, acknowledged = replay_bag(messages, args.rate, args.wait_s)
    print(f"replayed {len(messages)} messages on {topics} topics in {elapsed_s:.2f} s")
    if not acknowledged:
        print(
            f"warning: a subscriber did not acknowledge every message within {ACK_TIMEOUT_S:g} s "
            "after the last one; it may have missed some",
            file=sys.stderr,
        )
        return 1
    return 0


def command_repair(args: argparse.Namespace) -> int:
    """Write what a damaged (killed) MCAP recording still holds into a new, complete bag.

    The new bag is never written into the damaged one's folder.
    """
    check_apart(args.output, "-o", bag_inputs("the input", args.bag), "a new folder")
    output = new_dir(args.output, "-o")
    counts = repair_bag(input_bag(args.bag), output)
    total = sum(counts.values())
    print(f"wrote {total} messages on {len(counts)} topics to {output}")
    for topic, count in sorted(counts.items()):
        print(f"  {topic}: {count}")
    return 0


def register(verbs: Verbs) -> None:
    """Add ``audio2pose bag from-wav`` and ``audio2pose bag replay``."""
    bag = verbs.add_parser("bag", help="speech bags: make from WAV, replay, repair")
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
    replay.add_argument(
        "--topics",
        nargs="*",
        help="replay these topics (default: the audio only; topics that command the robot are "
        "replayed only when named, with a warning)",
    )
    replay.add_argument(
        "--wait-s",
        type=bounded_float(0.0, MAX_WAIT_S),
        default=10.0,
        help="wait this long for subscribers before starting (default 10)",
    )
    replay.set_defaults(func=command_replay)

    repair = sub.add_parser(
        "repair", help="a readable bag from what a killed MCAP recording still holds"
    )
    repair.add_argument("bag", metavar="BAG", help="the damaged bag folder or its .mcap file")
    repair.add_argument("-o", "--output", required=True, metavar="BAG", help="a new bag folder")
    repair.set_defaults(func=command_repair)

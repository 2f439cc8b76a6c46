"""rosbag2 files (MCAP by default) written and read with ``rosbags``, no ROS installation needed.

:func:`write_audio_bag` turns a speech signal into a bag of audio as a live microphone delivers
it, :func:`read_messages` iterates a bag, and :func:`read_bag_audio` decodes its audio for
offline synthesis. The type store knows the standard ROS 2 messages plus the two interface
packages this graph speaks that ``rosbags`` does not ship: audio_common_msgs
(ros-drivers/audio_common, ROS 2) and naoqi_bridge_msgs/JointAnglesWithSpeed (ros-naoqi). Their
definitions below are the upstream interface definitions.

Bags are untrusted input. Only the message types in :data:`KNOWN_MESSAGE_TYPES` (what the graph
publishes, records and consumes) are ever deserialized or replayed; a bag's CDR bytes are
checked with the type store before they are used, and invalid bytes are a :class:`BagError`
naming the topic and time. Decoding a bag's audio is capped at :data:`MAX_BAG_AUDIO_S` seconds
of 16 kHz output, checked before each message is decoded, so an AudioInfo claiming a tiny sample
rate cannot make a small bag grow into gigabytes.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from struct import error as struct_error
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import StoragePlugin
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from audio2pose_ros import topics
from audio2pose_ros.audio.pcm import S16LE_MONO_16K, PcmDecoder, PcmFormat, encode_pcm
from audio2pose_ros.errors import Audio2PoseError, ConfigurationError, InputError
from audio2pose_ros.timebase import SAMPLE_RATE_HZ
from audio2pose_ros.topics import absolute

EXTRA_MESSAGE_DEFINITIONS = {
    "audio_common_msgs/msg/AudioData": "uint8[] data\n",
    "audio_common_msgs/msg/AudioDataStamped": (
        "std_msgs/Header header\naudio_common_msgs/AudioData audio\n"
    ),
    "audio_common_msgs/msg/AudioInfo": (
        "uint8 channels\nuint32 sample_rate\nstring sample_format\nuint32 bitrate\n"
        "string coding_format\n"
    ),
    "naoqi_bridge_msgs/msg/JointAnglesWithSpeed": (
        "std_msgs/Header header\nstring[] joint_names\nfloat32[] joint_angles\nfloat32 speed\n"
        "uint8 relative\n"
    ),
}


def typestore() -> Typestore:
    """A ROS 2 (Humble-compatible) type store extended with the graph's extra message types."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    types: dict[str, Any] = {}
    for name, text in EXTRA_MESSAGE_DEFINITIONS.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


class BagError(InputError):
    """A bag cannot be read or does not hold what was asked for."""


# The message types this project publishes, records or consumes, and the rclpy module that
# defines each: nothing else in a bag is deserialized, and replay imports only these modules.
KNOWN_MESSAGE_TYPES = {
    "audio_common_msgs/msg/AudioData": "audio_common_msgs.msg",
    "audio_common_msgs/msg/AudioDataStamped": "audio_common_msgs.msg",
    "audio_common_msgs/msg/AudioInfo": "audio_common_msgs.msg",
    "naoqi_bridge_msgs/msg/JointAnglesWithSpeed": "naoqi_bridge_msgs.msg",
    "trajectory_msgs/msg/JointTrajectory": "trajectory_msgs.msg",
    "sensor_msgs/msg/JointState": "sensor_msgs.msg",
    "std_msgs/msg/Float32MultiArray": "std_msgs.msg",
    "std_msgs/msg/Bool": "std_msgs.msg",
    "std_msgs/msg/String": "std_msgs.msg",
    "diagnostic_msgs/msg/DiagnosticArray": "diagnostic_msgs.msg",
    "tf2_msgs/msg/TFMessage": "tf2_msgs.msg",
}
MAX_BAG_AUDIO_S = 4 * 3600.0  # decoded audio per bag: 4 h at 16 kHz is 0.9 GB of float32
# What a replay feeds a running graph unless topics are named: its input, the microphone. Every
# other known type commands the robot (joint_angles, trajectories, stop / enable) or stands in for
# one of the graph's own nodes (features, raw_trajectory, joint_states).
INPUT_MESSAGE_TYPES = frozenset(
    {
        "audio_common_msgs/msg/AudioData",
        "audio_common_msgs/msg/AudioDataStamped",
        "audio_common_msgs/msg/AudioInfo",
    }
)


@dataclass(frozen=True)
class ReplaySelection:
    """What a replay publishes, and the topics it leaves out or must warn about."""

    messages: list[BagMessage]
    left_out: tuple[str, ...]  # topics not replayed because they are not the graph's input
    commanding: tuple[str, ...]  # named topics that command the robot or the graph directly


def select_for_replay(messages: list[BagMessage], named: bool) -> ReplaySelection:
    """Keep the graph's input (audio) unless topics were ``named`` by the user.

    A bag made by ``audio2pose run --record`` also holds the commands the robot received:
    replaying them into a running graph would drive the robot past the motion filter and fight
    it. Named topics are replayed as asked, and the ones that are not input are reported so the
    user can be warned.
    """
    other = tuple(sorted({m.topic for m in messages if m.msgtype not in INPUT_MESSAGE_TYPES}))
    if named:
        return ReplaySelection(messages, (), other)
    kept = [m for m in messages if m.msgtype in INPUT_MESSAGE_TYPES]
    return ReplaySelection(kept, other, ())


def check_known_type(msgtype: str, where: str) -> None:
    """Refuse a message type outside :data:`KNOWN_MESSAGE_TYPES`.

    Raises:
        BagError: the type is not one this project knows; ``where`` names the bag and topic.
    """
    if msgtype not in KNOWN_MESSAGE_TYPES:
        raise BagError(
            f"{where}: message type {msgtype!r} is not one this project knows "
            f"({', '.join(sorted(KNOWN_MESSAGE_TYPES))})"
        )


def deserialize(store: Typestore, message: BagMessage, bag: str | Path) -> Any:
    """Decode one known message's CDR bytes with ``store``.

    Raises:
        BagError: the type is unknown, or the bytes are not valid CDR for it (the message names
            the bag, the topic and the time).
    """
    where = f"{bag}: {message.topic} at {message.timestamp_ns} ns"
    check_known_type(message.msgtype, where)
    try:
        return store.deserialize_cdr(message.data, message.msgtype)
    except (SerdeError, ValueError, IndexError, UnicodeDecodeError) as exc:
        # rosbags reports truncated or malformed CDR with these; the bytes are the bag's.
        raise BagError(f"{where}: invalid {message.msgtype} CDR ({exc})") from None


class BagWriter:
    """Write CDR-serialised messages to a new rosbag2 directory (MCAP or SQLite 3 storage).

    Use as a context manager; ``write`` takes bytes serialised by rclpy or by ``rosbags``.
    With ``flush_period_s`` (MCAP), what was written is closed into a chunk and handed to the
    operating system at least that often, so a recording killed with SIGKILL keeps all but its
    last ``flush_period_s``; :func:`repair_bag` makes a readable bag of what is left.
    """

    def __init__(
        self, path: str | Path, storage: str = "mcap", flush_period_s: float | None = None
    ) -> None:
        """Prepare a writer; the directory must not exist yet."""
        plugins = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
        if storage not in plugins:
            raise ValueError(f"storage {storage!r} is not one of {sorted(plugins)}")
        self.path = Path(path)
        self.store = typestore()
        self._writer = Writer(self.path, version=8, storage_plugin=plugins[storage])
        self._connections: dict[tuple[str, str], Any] = {}  # (topic, type) -> connection
        self.counts: dict[str, int] = {}  # messages written per topic (all its types)
        self._flush_period_s = flush_period_s if storage == "mcap" else None
        self._flushed_s = time.monotonic()

    def __enter__(self) -> BagWriter:
        """Open the bag."""
        self._writer.open()
        if self._flush_period_s is not None:
            self.flush()  # the MCAP header: a recording killed at once is still an MCAP file
        return self

    def flush(self) -> None:
        """Close the pending MCAP chunk and hand the file's bytes to the operating system.

        rosbags' MCAP writer keeps up to 1 MiB in its pending chunk and its file buffer, which a
        SIGKILL loses; its storage object has no public flush, so this reaches into it (rosbags
        is pinned in support/requirements.txt; test_recording.py fails if this stops working).
        """
        storage: Any = self._writer.storage  # rosbags' McapWriter (see above)
        if storage is None:
            return
        if storage.chunk.bio.tell():
            storage.close_chunk()
        storage.bio.flush()
        self._flushed_s = time.monotonic()

    def __exit__(self, *exc: object) -> None:
        """Close the bag (writes the MCAP summary / metadata.yaml)."""
        self._writer.close()

    def write(self, topic: str, msgtype: str, timestamp_ns: int, data: bytes) -> None:
        """Append one message under its own type.

        The first message of each (topic, type) pair creates that pair's connection: a topic
        recorded with two types keeps two connections, and bytes are never stored under a type
        they were not serialised with.
        """
        key = (topic, msgtype)
        if key not in self._connections:
            self._connections[key] = self._writer.add_connection(
                topic, msgtype, typestore=self.store
            )
        self._writer.write(self._connections[key], timestamp_ns, data)
        self.counts[topic] = self.counts.get(topic, 0) + 1
        if (
            self._flush_period_s is not None
            and time.monotonic() - self._flushed_s >= self._flush_period_s
        ):
            self.flush()


AUDIO_TOPIC = absolute(topics.AUDIO)  # where bags keep the audio: the root namespace
AUDIO_INFO_TOPIC = absolute(topics.AUDIO_INFO)
AUDIO_DATA_TYPE = "audio_common_msgs/msg/AudioData"
AUDIO_INFO_TYPE = "audio_common_msgs/msg/AudioInfo"
# The audio topics and the type each must have for :func:`read_bag_audio` to decode them.
AUDIO_TOPIC_TYPES = {AUDIO_INFO_TOPIC: AUDIO_INFO_TYPE, AUDIO_TOPIC: AUDIO_DATA_TYPE}
AUDIO_INFO_PERIOD_S = 5.0  # audio_capture republishes its latched AudioInfo every 5 s
MAX_CHUNK_BYTES = 1 << 20  # largest AudioData payload write_audio_bag cuts


@dataclass(frozen=True)
class Chunking:
    """How :func:`write_audio_bag` cuts audio into AudioData messages, like a live capture.

    Sizes are drawn uniformly in [min_bytes, max_bytes] (odd sizes included, so samples split
    across messages); each message is stamped when its last byte would have been captured, plus
    a uniform jitter of up to ``jitter_s``.
    """

    min_bytes: int = 640
    max_bytes: int = 4096
    jitter_s: float = 0.002
    seed: int = 0

    def __post_init__(self) -> None:
        """Refuse sizes that never finish (0 bytes) or cannot be drawn (min above max)."""
        if not 1 <= self.min_bytes <= self.max_bytes <= MAX_CHUNK_BYTES:
            raise ConfigurationError(
                f"chunk sizes need 1 <= min_bytes ({self.min_bytes}) <= max_bytes "
                f"({self.max_bytes}) <= {MAX_CHUNK_BYTES}"
            )
        if not 0.0 <= self.jitter_s <= 1.0:
            raise ConfigurationError(f"jitter_s {self.jitter_s} is not in [0, 1] s")
        if self.seed < 0:
            raise ConfigurationError(f"seed {self.seed} must not be negative")


@dataclass(frozen=True)
class BagMessage:
    """One stored message: time, topic, type name and CDR bytes."""

    timestamp_ns: int
    topic: str
    msgtype: str
    data: bytes


def audio_messages(signal_16k: np.ndarray, chunking: Chunking | None = None) -> list[BagMessage]:
    """Audio as audio_capture publishes it: S16LE AudioData chunks and periodic AudioInfo.

    Timestamps start at 0 ns (add the recording's start time when writing a bag).
    """
    chunking = chunking or Chunking()
    rng = np.random.default_rng(chunking.seed)
    payload = encode_pcm(signal_16k, S16LE_MONO_16K)
    store = typestore()
    info = store.types[AUDIO_INFO_TYPE](**S16LE_MONO_16K.audio_info_fields())
    info_bytes = bytes(store.serialize_cdr(info, AUDIO_INFO_TYPE))
    data_cls = store.types[AUDIO_DATA_TYPE]
    messages, offset, next_info_s = [], 0, 0.0
    while offset < len(payload):
        size = int(rng.integers(chunking.min_bytes, chunking.max_bytes + 1))
        chunk = payload[offset : offset + size]
        offset += len(chunk)
        t_s = offset / (2 * SAMPLE_RATE_HZ) + rng.uniform(0.0, chunking.jitter_s)
        if t_s >= next_info_s:
            messages.append(
                BagMessage(round(next_info_s * 1e9), AUDIO_INFO_TOPIC, AUDIO_INFO_TYPE, info_bytes)
            )
            next_info_s += AUDIO_INFO_PERIOD_S
        msg = data_cls(data=np.frombuffer(chunk, dtype=np.uint8))
        messages.append(
            BagMessage(
                round(t_s * 1e9),
                AUDIO_TOPIC,
                AUDIO_DATA_TYPE,
                bytes(store.serialize_cdr(msg, AUDIO_DATA_TYPE)),
            )
        )
    return messages


def write_audio_bag(
    signal_16k: np.ndarray,
    out: str | Path,
    chunking: Chunking | None = None,
    storage: str = "mcap",
    start_ns: int = 1_700_000_000_000_000_000,
) -> int:
    """Write 16 kHz mono audio to a new bag as :func:`audio_messages` chunks it.

    Returns:
        The number of AudioData messages.
    """
    messages = audio_messages(signal_16k, chunking)
    with BagWriter(out, storage) as bag:
        for message in messages:
            bag.write(message.topic, message.msgtype, start_ns + message.timestamp_ns, message.data)
    return sum(m.topic == AUDIO_TOPIC for m in messages)


MAX_CHUNK_BYTES_DECOMPRESSED = 64 << 20  # an MCAP chunk is read whole; rosbag2 writes ~1 MiB ones
MAX_FILE_BYTES_DECOMPRESSED = 2 << 30  # a file-compressed bag file is unpacked to disk first


def _mcap_chunks_bounded(path: Path) -> None:
    """Refuse an MCAP file whose chunks would decompress beyond the cap (a compression bomb)."""
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    try:
        with path.open("rb") as stream:
            summary = make_reader(stream).get_summary()
    except (McapError, OSError, ValueError, EOFError) as exc:
        raise BagError(f"{path}: not a readable MCAP file ({exc})") from None
    for index in summary.chunk_indexes if summary is not None else ():
        if index.uncompressed_size > MAX_CHUNK_BYTES_DECOMPRESSED:
            raise BagError(
                f"{path}: a chunk would decompress to {index.uncompressed_size} bytes; at most "
                f"{MAX_CHUNK_BYTES_DECOMPRESSED} are read (a compression bomb?)"
            )


def _compressed_file_bounded(path: Path) -> None:
    """Refuse a zstd-compressed bag file whose size once decompressed is unknown or too large."""
    import zstandard

    with path.open("rb") as stream:
        header = stream.read(18)
    size = zstandard.frame_content_size(header) if len(header) >= 4 else -1
    if size < 0 or size > MAX_FILE_BYTES_DECOMPRESSED:
        raise BagError(
            f"{path}: decompresses to {'an unknown size' if size < 0 else f'{size} bytes'}; "
            f"at most {MAX_FILE_BYTES_DECOMPRESSED} bytes are unpacked"
        )


def check_bag_files(bag: str | Path, mcap_summaries: bool = True) -> None:
    """Refuse a bag that would hang, fill memory or fill the disk before rosbags reads it.

    Every file of a bag folder (and a single-file bag) must be a regular file: reading a FIFO
    blocks forever and ``/dev/zero`` never ends. ``metadata.yaml`` is read with the project's
    bounded YAML reader (size cap, no aliases: a few kilobytes of nested aliases expand to
    gigabytes). MCAP chunks may not decompress beyond :data:`MAX_CHUNK_BYTES_DECOMPRESSED` each,
    zstd-compressed files not beyond :data:`MAX_FILE_BYTES_DECOMPRESSED`. Without
    ``mcap_summaries`` MCAP files are not looked into (a damaged one has no summary).

    Raises:
        BagError: naming the file and why it is refused.
    """
    import stat

    from audio2pose_ros.files import read_yaml_file

    path = Path(bag)
    if not path.exists():
        return  # rosbags says it is missing, in its own words
    try:
        files = sorted(path.iterdir()) if path.is_dir() else [path]
        for file in files:
            if not stat.S_ISREG(file.stat().st_mode):
                raise BagError(f"{file}: not a regular file (a device, FIFO or socket?)")
    except OSError as exc:
        raise BagError(f"{path}: cannot read ({exc.strerror or exc})") from None
    for file in files:
        if file.name == "metadata.yaml":
            read_yaml_file(file, "bag metadata", BagError)
        elif file.suffix == ".mcap" and mcap_summaries:
            _mcap_chunks_bounded(file)
        elif file.suffix == ".zstd":
            _compressed_file_bounded(file)


def _open_reader(bag: str | Path) -> AnyReader:
    """An open AnyReader on ``bag`` (checked by :func:`check_bag_files`), or a BagError."""
    check_bag_files(bag)
    try:
        reader = AnyReader([Path(bag)], default_typestore=typestore())
        reader.open()
    except (AnyReaderError, OSError, ValueError, KeyError, TypeError) as exc:
        # rosbags raises these for a missing, unreadable or malformed bag (metadata, MCAP
        # records, SQLite schema); all are about the file.
        raise BagError(f"{bag}: cannot open as a rosbag2 ({exc})") from None
    return reader


def bag_topics(bag: str | Path) -> dict[str, str]:
    """Topic -> message type name of every connection in a bag (nothing is deserialized).

    Raises:
        BagError: the bag cannot be opened.
    """
    reader = _open_reader(bag)
    try:
        return {c.topic: c.msgtype for c in reader.connections}
    finally:
        reader.close()


def read_messages(
    bag: str | Path,
    topics: Iterable[str] | None = None,
    types: Mapping[str, str] | None = None,
) -> Iterator[BagMessage]:
    """Messages of a rosbag2 (MCAP or SQLite 3) in time order, optionally only ``topics``.

    Only connections whose type is in :data:`KNOWN_MESSAGE_TYPES` are read; with ``topics``
    given, a wanted topic of another type is refused. ``types`` maps a topic to the one type
    its messages must have (a decoder relies on it): a connection of another type on that
    topic is refused, before any message is read, even when the bag also holds one of the
    expected type.

    Raises:
        BagError: the bag cannot be opened, or a wanted topic has an unknown type or is not of
            the type ``types`` expects.
    """
    wanted = set(topics) if topics is not None else None
    expected = dict(types or {})
    reader = _open_reader(bag)
    try:
        connections = [c for c in reader.connections if wanted is None or c.topic in wanted]
        for connection in connections:
            if wanted is not None:
                check_known_type(connection.msgtype, f"{bag}: {connection.topic}")
            if expected.get(connection.topic, connection.msgtype) != connection.msgtype:
                raise BagError(
                    f"{bag}: {connection.topic} is {connection.msgtype}, expected "
                    f"{expected[connection.topic]}"
                )
        connections = [c for c in connections if c.msgtype in KNOWN_MESSAGE_TYPES]
        if not connections:  # rosbags reads every connection when given none
            return
        for conn, timestamp, data in reader.messages(connections=connections):
            yield BagMessage(timestamp, conn.topic, conn.msgtype, bytes(data))
    finally:
        reader.close()


def read_checked_messages(
    bag: str | Path,
    topics: Iterable[str] | None = None,
    types: Mapping[str, str] | None = None,
) -> list[BagMessage]:
    """:func:`read_messages` as a list, each message's CDR checked by deserializing it.

    Use it before publishing a bag's bytes: a subscriber then never receives bytes it cannot
    deserialize. Memory is bounded by the bag's size.

    Raises:
        BagError: the bag cannot be opened, or a message has an unknown type, a type other
            than ``types`` expects for its topic, or invalid CDR.
    """
    store = typestore()
    messages = list(read_messages(bag, topics, types))
    for message in messages:
        deserialize(store, message, bag)
    return messages


def read_bag_audio(bag: str | Path) -> np.ndarray:
    """Decode a bag's AudioData as its AudioInfo messages describe, to 16 kHz mono float32.

    A changed AudioInfo switches the decoder (as audio_features_node does); audio before the
    first AudioInfo cannot be decoded and raises. The output is capped at
    :data:`MAX_BAG_AUDIO_S`: each message's output size is predicted from its byte count and
    the sample rate before it is decoded.

    Raises:
        BagError: an audio topic holds a connection of another type than
            :data:`AUDIO_TOPIC_TYPES` names (AudioDataStamped on /audio/audio, say), no
            AudioInfo precedes the audio, an AudioInfo is unusable, a message is not valid CDR,
            the decoded audio would exceed the cap, or the bag holds no audio.
    """
    store = typestore()
    decoder: PcmDecoder | None = None
    pieces: list[np.ndarray] = []
    budget = MAX_BAG_AUDIO_S * SAMPLE_RATE_HZ  # output samples left
    for message in read_messages(bag, AUDIO_TOPIC_TYPES, AUDIO_TOPIC_TYPES):
        msg = deserialize(store, message, bag)
        if message.topic == AUDIO_INFO_TOPIC:
            try:
                fmt = PcmFormat.from_audio_info(
                    msg.channels, msg.sample_rate, msg.sample_format, msg.coding_format
                )
            except Audio2PoseError as exc:  # pcm refuses the format (UnsupportedAudioFormat)
                raise BagError(
                    f"{bag}: unusable AudioInfo at {message.timestamp_ns} ns ({exc})"
                ) from None
            if decoder is None or decoder.fmt != fmt:
                if decoder is not None:
                    pieces.append(decoder.flush())
                decoder = PcmDecoder(fmt)
        elif decoder is None:
            raise BagError(f"{bag}: AudioData at {message.timestamp_ns} ns before any AudioInfo")
        else:
            fmt = decoder.fmt
            budget -= (len(msg.data) / fmt.frame_bytes + 1) * SAMPLE_RATE_HZ / fmt.sample_rate_hz
            if budget < 0:
                raise BagError(
                    f"{bag}: its audio at {fmt.sample_rate_hz} Hz decodes to more than "
                    f"{MAX_BAG_AUDIO_S:g} s at {SAMPLE_RATE_HZ} Hz"
                )
            pieces.append(decoder.feed(bytes(msg.data)))
    if decoder is None:
        raise BagError(f"{bag}: no {AUDIO_INFO_TOPIC} / {AUDIO_TOPIC} messages")
    pieces.append(decoder.flush())
    return np.concatenate(pieces).astype(np.float32)


def repair_bag(damaged: str | Path, out: str | Path) -> dict[str, int]:
    """Write the messages a damaged MCAP recording still holds into a new, complete bag.

    A recording killed before it closed has no summary, no footer and no ``metadata.yaml``:
    rosbags cannot open it. Its records are read in file order with the mcap library's stream
    reader up to the first incomplete one; every message of a known type is written to ``out``
    (a new rosbag2 folder, MCAP). ``damaged`` is a bag folder or its ``.mcap`` file.

    Returns:
        Messages written, per topic.

    Raises:
        BagError: no MCAP file, or not one (its magic bytes), or nothing readable in it.
    """
    from mcap.exceptions import McapError
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader

    path = Path(damaged)
    files = sorted(path.glob("*.mcap")) if path.is_dir() else [path]
    if not files:
        raise BagError(f"{path}: no .mcap file to repair")
    check_bag_files(path, mcap_summaries=False)  # the stream reader bounds each record itself
    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, str]] = {}
    messages: list[BagMessage] = []
    for file in files:
        try:
            with file.open("rb") as stream:
                for record in StreamReader(
                    stream, record_size_limit=MAX_CHUNK_BYTES_DECOMPRESSED
                ).records:
                    if isinstance(record, Schema):
                        schemas[record.id] = record.name
                    elif isinstance(record, Channel):
                        channels[record.id] = (record.topic, schemas.get(record.schema_id, ""))
                    elif isinstance(record, Message) and record.channel_id in channels:
                        topic, msgtype = channels[record.channel_id]
                        if msgtype in KNOWN_MESSAGE_TYPES:
                            messages.append(
                                BagMessage(record.log_time, topic, msgtype, bytes(record.data))
                            )
        except (McapError, EOFError, ValueError, struct_error):
            pass  # the end of what was written before the recording died
    if not messages:
        raise BagError(f"{path}: no readable messages of a known type")
    messages.sort(key=lambda m: m.timestamp_ns)
    with BagWriter(out) as bag:
        for message in messages:
            bag.write(message.topic, message.msgtype, message.timestamp_ns, message.data)
        return dict(bag.counts)

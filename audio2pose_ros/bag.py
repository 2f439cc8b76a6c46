"""rosbag2 files (MCAP by default) written and read with ``rosbags``, no ROS installation needed.

:func:`write_audio_bag` turns a speech signal into a bag of audio as a live microphone delivers
it, :func:`read_messages` iterates a bag, and :func:`read_bag_audio` decodes its audio for
offline synthesis. The type store knows the standard ROS 2 messages plus the two interface
packages this graph speaks that ``rosbags`` does not ship: audio_common_msgs
(ros-drivers/audio_common, ROS 2) and naoqi_bridge_msgs/JointAnglesWithSpeed (ros-naoqi). Their
definitions below are the upstream interface definitions.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import StoragePlugin
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from audio2pose_ros.audio.pcm import S16LE_MONO_16K, PcmDecoder, PcmFormat, encode_pcm
from audio2pose_ros.errors import InputError

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


class BagWriter:
    """Write CDR-serialised messages to a new rosbag2 directory (MCAP or SQLite 3 storage).

    Use as a context manager; ``write`` takes bytes serialised by rclpy or by ``rosbags``.
    """

    def __init__(self, path: str | Path, storage: str = "mcap") -> None:
        """Prepare a writer; the directory must not exist yet."""
        plugins = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
        if storage not in plugins:
            raise ValueError(f"storage {storage!r} is not one of {sorted(plugins)}")
        self.path = Path(path)
        self.store = typestore()
        self._writer = Writer(self.path, version=8, storage_plugin=plugins[storage])
        self._connections: dict[str, Any] = {}
        self.counts: dict[str, int] = {}

    def __enter__(self) -> BagWriter:
        """Open the bag."""
        self._writer.open()
        return self

    def __exit__(self, *exc: object) -> None:
        """Close the bag (writes the MCAP summary / metadata.yaml)."""
        self._writer.close()

    def write(self, topic: str, msgtype: str, timestamp_ns: int, data: bytes) -> None:
        """Append one message; the first message on a topic creates its connection."""
        if topic not in self._connections:
            self._connections[topic] = self._writer.add_connection(
                topic, msgtype, typestore=self.store
            )
            self.counts[topic] = 0
        self._writer.write(self._connections[topic], timestamp_ns, data)
        self.counts[topic] += 1


AUDIO_TOPIC = "/audio/audio"
AUDIO_INFO_TOPIC = "/audio/audio_info"
AUDIO_DATA_TYPE = "audio_common_msgs/msg/AudioData"
AUDIO_INFO_TYPE = "audio_common_msgs/msg/AudioInfo"
AUDIO_INFO_PERIOD_S = 5.0  # audio_capture republishes its latched AudioInfo every 5 s


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
        t_s = offset / (2 * 16000) + rng.uniform(0.0, chunking.jitter_s)
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


def read_messages(bag: str | Path, topics: Iterable[str] | None = None) -> Iterator[BagMessage]:
    """Messages of a rosbag2 (MCAP or SQLite 3) in time order, optionally only ``topics``.

    Raises:
        BagError: the bag cannot be opened.
    """
    wanted = set(topics) if topics is not None else None
    try:
        reader = AnyReader([Path(bag)], default_typestore=typestore())
        reader.open()
    except (AnyReaderError, OSError, ValueError) as exc:
        raise BagError(f"{bag}: cannot open as a rosbag2 ({exc})") from None
    try:
        connections = [c for c in reader.connections if wanted is None or c.topic in wanted]
        for conn, timestamp, data in reader.messages(connections=connections):
            yield BagMessage(timestamp, conn.topic, conn.msgtype, bytes(data))
    finally:
        reader.close()


def read_bag_audio(bag: str | Path) -> np.ndarray:
    """Decode a bag's AudioData as its AudioInfo messages describe, to 16 kHz mono float32.

    A changed AudioInfo switches the decoder (as audio_features_node does); audio before the
    first AudioInfo cannot be decoded and raises.

    Raises:
        BagError: no AudioInfo precedes the audio, or the bag holds no audio.
    """
    store = typestore()
    decoder: PcmDecoder | None = None
    pieces: list[np.ndarray] = []
    for message in read_messages(bag, (AUDIO_TOPIC, AUDIO_INFO_TOPIC)):
        msg = store.deserialize_cdr(message.data, message.msgtype)
        if message.topic == AUDIO_INFO_TOPIC:
            fmt = PcmFormat.from_audio_info(
                msg.channels, msg.sample_rate, msg.sample_format, msg.coding_format
            )
            if decoder is None or decoder.fmt != fmt:
                if decoder is not None:
                    pieces.append(decoder.flush())
                decoder = PcmDecoder(fmt)
        elif decoder is None:
            raise BagError(f"{bag}: AudioData at {message.timestamp_ns} ns before any AudioInfo")
        else:
            pieces.append(decoder.feed(bytes(msg.data)))
    if decoder is None:
        raise BagError(f"{bag}: no {AUDIO_INFO_TOPIC} / {AUDIO_TOPIC} messages")
    pieces.append(decoder.flush())
    return np.concatenate(pieces).astype(np.float32)

"""rosbag2 files (MCAP by default) written and read with ``rosbags``, no ROS installation needed.

The type store knows the standard ROS 2 messages plus the two interface packages this graph
speaks that ``rosbags`` does not ship: audio_common_msgs (ros-drivers/audio_common, ROS 2) and
naoqi_bridge_msgs/JointAnglesWithSpeed (ros-naoqi). Their definitions below are the upstream
interface definitions.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import StoragePlugin
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

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

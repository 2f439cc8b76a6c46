"""``audio2pose run``: start the node graph as processes, play a WAV into it, record its output.

This is what ``ros2 launch audio2pose_ros pepper.launch.py`` does, for machines without a ROS
distro: the same three executables, each its own process, with the same parameter file. The
player publishes audio_common_msgs AudioInfo (latched) and AudioData chunks in real time; the
recorder writes every command the robot would receive to a rosbag2 (MCAP).
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path

import rclpy
from audio_common_msgs.msg import AudioData, AudioInfo
from naoqi_bridge_msgs.msg import JointAnglesWithSpeed
from rclpy.node import Node
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros.audio.pcm import read_wav
from audio2pose_ros.bag import (
    AUDIO_INFO_TOPIC,
    AUDIO_TOPIC,
    BagError,
    BagMessage,
    BagWriter,
    Chunking,
    audio_messages,
    read_messages,
)
from audio2pose_ros.nodes.common import LATCHED_QOS
from audio2pose_ros.resources import share_path

NODE_EXECUTABLES = ("audio_features_node", "inference_node", "motion_filter_node")
RECORDED_TOPICS = {
    "/joint_angles": (JointAnglesWithSpeed, "naoqi_bridge_msgs/msg/JointAnglesWithSpeed"),
    "/joint_trajectory_controller/joint_trajectory": (
        JointTrajectory,
        "trajectory_msgs/msg/JointTrajectory",
    ),
    "/joint_states": (JointState, "sensor_msgs/msg/JointState"),
    "/raw_trajectory": (JointTrajectory, "trajectory_msgs/msg/JointTrajectory"),
}


def executable_command(name: str) -> list[str]:
    """The console script ``name`` next to this interpreter, else ``python -m`` its module."""
    script = Path(sys.executable).parent / name
    if script.is_file() and os.access(script, os.X_OK):
        return [str(script)]
    found = shutil.which(name)
    if found:
        return [found]
    return [sys.executable, "-m", f"audio2pose_ros.nodes.{name}"]


class NodeSupervisor:
    """Runs the node processes and respawns one that dies, like ``respawn=True`` in a launch file.

    A node that exits is restarted after ``respawn_delay_s`` (its log file is appended to). A node
    that dies more than ``max_restarts`` times within ``restart_window_s`` is given up on, with a
    message, rather than restarted forever. Configuration errors do not make nodes exit (see
    :class:`~audio2pose_ros.nodes.common.ConfigurationErrorNode`), so they never reach here.
    """

    def __init__(
        self,
        commands: dict[str, list[str]],
        log_dir: Path | None,
        respawn_delay_s: float = 1.0,
        max_restarts: int = 5,
        restart_window_s: float = 60.0,
    ) -> None:
        """Remember how to start each node; :meth:`start` starts them."""
        self.commands = commands
        self.log_dir = log_dir
        self.respawn_delay_s = respawn_delay_s
        self.max_restarts = max_restarts
        self.restart_window_s = restart_window_s
        self.processes: dict[str, subprocess.Popen] = {}
        self.restarts: dict[str, list[float]] = {name: [] for name in commands}
        self.given_up: set[str] = set()
        self._stopping = threading.Event()
        self._thread = threading.Thread(target=self._watch, name="node-supervisor", daemon=True)

    def _spawn(self, name: str, mode: str) -> None:
        stdout = None
        if self.log_dir is not None:
            self.log_dir.mkdir(parents=True, exist_ok=True)
            stdout = (self.log_dir / f"{name}.log").open(mode)
        self.processes[name] = subprocess.Popen(
            self.commands[name], stdout=stdout, stderr=subprocess.STDOUT if stdout else None
        )
        if stdout is not None:
            stdout.close()  # the child holds its own descriptor

    def start(self) -> None:
        """Start every node and the watchdog thread."""
        for name in self.commands:
            self._spawn(name, "w")
        self._thread.start()

    def _watch(self) -> None:
        while not self._stopping.wait(0.2):
            for name, process in list(self.processes.items()):
                if process.poll() is None or name in self.given_up:
                    continue
                now = time.monotonic()
                recent = [t for t in self.restarts[name] if now - t < self.restart_window_s]
                if len(recent) >= self.max_restarts:
                    self.given_up.add(name)
                    print(
                        f"audio2pose run: {name} died {len(recent) + 1} times within "
                        f"{self.restart_window_s:.0f} s; not restarting it again",
                        file=sys.stderr,
                        flush=True,
                    )
                    continue
                print(
                    f"audio2pose run: {name} exited with code {process.returncode}; "
                    f"restarting it in {self.respawn_delay_s:.1f} s",
                    file=sys.stderr,
                    flush=True,
                )
                if self._stopping.wait(self.respawn_delay_s):
                    return
                self.restarts[name] = [*recent, now]
                self._spawn(name, "a")

    def stop(self) -> None:
        """Stop the watchdog, then the nodes (SIGINT, then SIGKILL after 5 s)."""
        self._stopping.set()
        if self._thread.is_alive():
            self._thread.join()
        for process in self.processes.values():
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
        deadline = time.monotonic() + 5.0
        for process in self.processes.values():
            try:
                process.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


@contextmanager
def node_graph(
    params_file: Path | None = None,
    overrides: Sequence[str] = (),
    log_dir: Path | None = None,
) -> Iterator[NodeSupervisor]:
    """Run the three nodes as supervised processes for the duration of the context.

    Args:
        params_file: ROS parameter YAML (default: the package's config/pepper.yaml).
        overrides: extra ``name:=value`` parameters for every node.
        log_dir: where each node's output goes (``<node>.log``); ``None`` inherits the terminal.
    """
    params = params_file or share_path("config", "pepper.yaml")
    commands = {}
    for name in NODE_EXECUTABLES:
        command = [*executable_command(name), "--ros-args", "--params-file", str(params)]
        for override in overrides:
            command += ["-p", override]
        commands[name] = command
    supervisor = NodeSupervisor(commands, log_dir)
    try:
        supervisor.start()
        yield supervisor
    finally:
        supervisor.stop()


@dataclass
class PlaybackResult:
    """What a run recorded."""

    audio_s: float
    chunks_sent: int
    recorded_s: float
    counts: dict[str, int] = field(default_factory=dict)
    bag: Path | None = None


class PlayerRecorder(Node):
    """Publishes a WAV as audio_common_msgs in real time and records the graph's commands."""

    def __init__(self, bag: BagWriter | None) -> None:
        """Create the audio publishers and one recording subscription per command topic."""
        super().__init__("audio2pose_player")
        self.bag = bag
        self.recording = False
        self.counts = dict.fromkeys(RECORDED_TOPICS, 0)
        self.poses_seen = 0
        self.audio_pub = self.create_publisher(AudioData, AUDIO_TOPIC, 100)
        self.info_pub = self.create_publisher(AudioInfo, AUDIO_INFO_TOPIC, LATCHED_QOS)
        self.create_subscription(JointTrajectory, "/raw_trajectory", self._on_pose, 100)
        for topic, (msg_type, type_name) in RECORDED_TOPICS.items():
            self.create_subscription(
                msg_type, topic, self._recorder(topic, type_name), 100, raw=True
            )

    def _on_pose(self, msg: JointTrajectory) -> None:
        self.poses_seen += len(msg.points)

    def _recorder(self, topic: str, type_name: str) -> Callable[[bytes], None]:
        def record(data: bytes) -> None:
            if not self.recording:
                return
            self.counts[topic] += 1
            if self.bag is not None:
                self.bag.write(topic, type_name, self.get_clock().now().nanoseconds, data)

        return record

    def publish_audio(self, message: BagMessage) -> None:
        """Publish a serialised AudioData / AudioInfo, and record it while recording."""
        publisher = self.info_pub if message.topic == AUDIO_INFO_TOPIC else self.audio_pub
        publisher.publish(message.data)
        if self.recording and self.bag is not None:
            self.bag.write(
                message.topic, message.msgtype, self.get_clock().now().nanoseconds, message.data
            )

    def spin_until(self, deadline_s: float, done: Callable[[], bool] | None = None) -> bool:
        """Process callbacks until ``deadline_s`` (monotonic) or until ``done()`` is true."""
        while time.monotonic() < deadline_s:
            rclpy.spin_once(self, timeout_sec=0.005)
            if done is not None and done():
                return True
        return done is None

    def warm_up(self, timeout_s: float) -> None:
        """Send silence until poses come back, so every link of the graph has matched.

        DDS discovery is asymmetric: a node may see our subscription before its own publisher
        has matched the next node, and samples sent before that are lost. Chunks of 160
        samples keep the feature extractor aligned to whole 10 ms frames.
        """
        silence = AudioData(data=bytes(2 * 160))

        def poses_arrive() -> bool:
            self.audio_pub.publish(silence)
            self.spin_until(time.monotonic() + 0.02)
            return self.poses_seen > 0

        if not self.spin_until(time.monotonic() + timeout_s, poses_arrive):
            raise TimeoutError(
                f"the node graph did not answer within {timeout_s} s (see the node logs)"
            )
        self.spin_until(time.monotonic() + 0.3)


def audio_source(path: Path, chunking: Chunking | None = None) -> list[BagMessage]:
    """The audio messages to play: a WAV cut like a live capture, or a bag's audio topics."""
    if path.suffix.lower() == ".wav":
        samples, _ = read_wav(path)
        return audio_messages(samples, chunking)
    messages = list(read_messages(path, (AUDIO_TOPIC, AUDIO_INFO_TOPIC)))
    if not any(m.topic == AUDIO_TOPIC for m in messages):
        raise BagError(f"{path}: no {AUDIO_TOPIC} messages to play")
    start = messages[0].timestamp_ns
    return [replace(m, timestamp_ns=m.timestamp_ns - start) for m in messages]


def play_and_record(
    messages: Sequence[BagMessage],
    bag_path: Path | None,
    rate: float = 1.0,
    tail_s: float = 2.0,
    startup_timeout_s: float = 60.0,
) -> PlaybackResult:
    """Publish audio messages with their timing (``rate`` x faster); record what the graph sends.

    Must run while :func:`node_graph` is up, inside an initialised rclpy context. Recording
    starts with the first message and ends ``tail_s`` after the last one, so the bag also shows
    the glide back to the neutral pose.

    Raises:
        TimeoutError: the graph did not come up within ``startup_timeout_s``.
    """
    first_info = next((m for m in messages if m.topic == AUDIO_INFO_TOPIC), None)
    with ExitStack() as stack:
        bag = stack.enter_context(BagWriter(bag_path)) if bag_path else None
        node = PlayerRecorder(bag)
        stack.callback(node.destroy_node)
        if first_info is not None:
            node.publish_audio(first_info)
        node.warm_up(startup_timeout_s)
        node.recording = True
        start = time.monotonic()
        for message in messages:
            node.spin_until(start + message.timestamp_ns * 1e-9 / rate)
            node.publish_audio(message)
        node.spin_until(time.monotonic() + tail_s)
        return PlaybackResult(
            audio_s=messages[-1].timestamp_ns * 1e-9 if messages else 0.0,
            chunks_sent=sum(m.topic == AUDIO_TOPIC for m in messages),
            recorded_s=time.monotonic() - start,
            counts=dict(node.counts),
            bag=bag_path,
        )


def run_graph(
    play: Path | None,
    record: Path | None,
    params_file: Path | None,
    overrides: Sequence[str],
    log_dir: Path | None,
    rate: float = 1.0,
) -> PlaybackResult | None:
    """Start the graph; with ``play`` (a WAV or a bag) play it and return what was recorded.

    Without ``play`` the graph runs until Ctrl-C or until a node exits.
    """
    messages = audio_source(play) if play is not None else None
    with node_graph(params_file, overrides, log_dir) as supervisor:
        if messages is None:
            try:
                while len(supervisor.given_up) < len(NODE_EXECUTABLES):
                    time.sleep(0.2)
            except KeyboardInterrupt:
                pass
            return None
        with rclpy.init():
            return play_and_record(messages, record, rate=rate)


def summarize(result: PlaybackResult) -> str:
    """Human-readable summary of a playback."""
    lines = [
        f"played {result.audio_s:.2f} s of audio in {result.chunks_sent} messages; recorded "
        f"{result.recorded_s:.2f} s (speech and {result.recorded_s - result.audio_s:.1f} s after)"
    ]
    for topic, count in result.counts.items():
        lines.append(f"  {topic}: {count} messages ({count / result.recorded_s:.0f} Hz)")
    if result.bag is not None:
        lines.append(f"recorded to {result.bag}")
    return "\n".join(lines)

"""console_node: the operator's web console, a page and a WebSocket, next to the node graph.

The page (``web/``, served from the package's share directory) captures the operator's
microphone, shows the robot in 3D and has a stop button; the server
(:mod:`audio2pose_ros.console.server`, aiohttp in its own thread and asyncio loop) checks every
browser message and calls this node, which speaks ROS:

Publications:
    audio/audio (audio_common_msgs/AudioData): the floor holder's voice, 16 kHz mono S16LE in
        the page's 20 ms chunks, as audio_capture publishes a microphone.
    audio/audio_info (audio_common_msgs/AudioInfo, transient local): the format, latched and
        republished every :data:`AUDIO_INFO_PERIOD_S` like audio_capture's.
    stop, enable (std_msgs/Bool, transient local): the page's stop button and enable switch, as
        motion_filter_node expects them.
    /diagnostics: heartbeat, operators, floor, audio published and refused, wrong tokens, who
        holds the stop, latency, pages watching the room and what they were sent; WARN while
        the camera that sent pictures has sent none for
        :data:`~audio2pose_ros.console.room_feed.CAMERA_STALE_S` (naming the topic and the last
        picture's age, :class:`~audio2pose_ros.console.room_feed.FeedWatch`), OK again when
        pictures come back.
Subscriptions:
    joint_angles (naoqi_bridge_msgs/JointAnglesWithSpeed) and commanded_joint_states
        (sensor_msgs/JointState): the commanded pose for the 3D view, and the commands that end
        the latency measurement (:mod:`audio2pose_ros.console.latency`).
    joint_states (sensor_msgs/JointState): the measured pose of a robot or simulator, drawn as
        a ghost when present.
    raw_trajectory (its arrival only): pairs audio chunks with the poses they caused.
    stop, enable: their latched state, shown in the page.
    camera/front/image_raw (sensor_msgs/Image): the robot's camera, as JPEG to every identified
        page, at most :data:`MAX_PICTURES_PER_S` a second.
    audio (naoqi_bridge_msgs/AudioBuffer): the robot's microphones, 16 kHz mono to every
        identified page, the operator's own voice removed
        (:class:`~audio2pose_ros.console.room_feed.EchoCanceller`).

    The pictures and the microphones are only handed to the room's own thread
    (:class:`~audio2pose_ros.console.room_worker.RoomWorker`), which decodes, removes the echo
    and encodes: the executor (the heartbeat, the latched stop) and the lock the pages'
    snapshots take never wait on that work; what waits too long there is dropped and counted.
    /diagnostics: the health of every node, shown in the page; of the voice node
        (``voice_node``), its three latencies, the delay and the offset
        (:mod:`~audio2pose_ros.console.voice_status`).
Services used:
    emergency_stop (std_srvs/Trigger, motion_filter_node's): asked at every press of STOP,
        beside the latched topic; its answers counted on /diagnostics.
    <filter_node>/set_parameters, get_parameters (rcl_interfaces): the filter's live style
        parameters (:data:`~audio2pose_ros.motion.style.STYLE_FIELDS`: size and tempo per part,
        the arms' rest and height) set from the page (sliders, a preset, the learned style)
        and back to the values they had before the console's first change.
    <inference_node>/set_parameters, get_parameters: its ``model_path``, set to a learned
        personal model folder (the node blends that model in, no restart) and back to the value
        it had before the console's first change; ``model_path`` in the status, a refusal
        shown with its reason.
    <voice_node>/set_parameters, get_parameters: the voice node's ``muted``, the operator's
        choice in the page.

    Each is read back every :data:`~audio2pose_ros.ros.kept_parameters.READ_BACK_S` for the
    page, and the console keeps the operator's last choice in force: a node restarted
    meanwhile (it came back with its start-up values) is set again, with a warning in the log
    (:class:`~audio2pose_ros.ros.kept_parameters.KeptParameters`).

Parameters: :class:`~audio2pose_ros.console.settings.ConsoleSettings` (all read-only). A network
bind without certificate, key or a long enough token, a certificate that does not load or an
address that cannot be bound is a configuration error: one line, exit status 78.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from typing import Any

import numpy as np
from audio_common_msgs.msg import AudioData, AudioInfo
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from naoqi_bridge_msgs.msg import AudioBuffer, JointAnglesWithSpeed
from rcl_interfaces.msg import ParameterType
from rclpy.client import Client
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.task import Future
from sensor_msgs.msg import Image, JointState
from std_msgs.msg import Bool
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros import topics
from audio2pose_ros.audio.pcm import S16LE_MONO_16K
from audio2pose_ros.console.access import resolve_access
from audio2pose_ros.console.latency import VoiceLatency
from audio2pose_ros.console.protocol import AudioFrame
from audio2pose_ros.console.room_feed import FeedWatch, RoomItem
from audio2pose_ros.console.room_worker import MicrophoneBlock, Picture, RoomWorker
from audio2pose_ros.console.server import ConsoleServer
from audio2pose_ros.console.server_thread import ServerThread
from audio2pose_ros.console.settings import ConsoleSettings
from audio2pose_ros.console.voice_status import VOICE_KEYS, RobotSeen, voice_view
from audio2pose_ros.motion.style import STYLE_FIELDS
from audio2pose_ros.parameters import settings_from, specs_of
from audio2pose_ros.resources import share_path
from audio2pose_ros.robot.description import load_robot
from audio2pose_ros.ros.diagnosed_node import STALE_AFTER_S, DiagnosedNode, status_name
from audio2pose_ros.ros.kept_parameters import KeptParameters
from audio2pose_ros.ros.messages import stamp_s
from audio2pose_ros.ros.node_parameters import NodeParameters
from audio2pose_ros.ros.qos import LATCHED_QOS
from audio2pose_ros.ros.spin import run_node
from audio2pose_ros.ros.supervisor_pipe import to_terminal

PARAMETERS = specs_of(ConsoleSettings)
AUDIO_INFO_PERIOD_S = 5.0  # audio_capture republishes its AudioInfo this often
MEASURED_TIMEOUT_S = 2.0  # measured joint states older than this: no ghost robot
MICROPHONES_TIMEOUT_S = 2.0  # the robot's microphones not heard for this long: none
HEALTH_FORGET_S = 30.0  # a diagnostic status not heard for this long leaves the page
MAX_HEALTH_STATUSES = 32
MAX_HEALTH_MESSAGE_CHARS = 240
MAX_DIAGNOSTICS_BYTES = 1 << 18  # a DiagnosticArray larger than this is dropped undecoded
MAX_JOINT_STATE_BYTES = 65536  # as motion_filter_node's
# Listening only: best effort matches reliable publishers and never slows them down.
LISTEN_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=50, reliability=ReliabilityPolicy.BEST_EFFORT
)
# The camera: only the newest picture matters; older ones are dropped before they arrive.
CAMERA_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.BEST_EFFORT
)
MAX_PICTURES_PER_S = 15.0  # pictures encoded for the pages at most; the rest are skipped
MAX_IMAGE_BYTES = 1280 * 960 * 3 + 4096  # the largest picture taken (room_feed's limit)
MAX_MICROPHONE_BYTES = 1 << 20  # naoqi_driver's buffers are 64 KiB
AUDIO_PUBLISH_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE
)


def _taken_s(stamp: Any) -> float:
    """A header stamp as wall-clock seconds; now when it is unset or in the future."""
    now = time.time()
    taken = stamp_s(stamp)
    return taken if 0.0 < taken <= now else now


def _level(level: object) -> int:
    """A DiagnosticStatus level as an int (rclpy gives a one-byte ``bytes``)."""
    return level[0] if isinstance(level, bytes) and level else int(level)  # type: ignore[call-overload]


class ConsoleNode(DiagnosedNode):
    """Serve the console and carry its audio, stop, enable and style into the graph."""

    def __init__(self) -> None:
        """Declare parameters, wire topics and services, start the server thread.

        Raises:
            ConfigurationError: a refused parameter, bind, certificate or token.
        """
        super().__init__("console_node")
        self.server_thread: ServerThread | None = None  # rclpy may destroy a half-built node
        self.parameters = NodeParameters(self, PARAMETERS)
        self.settings: ConsoleSettings = settings_from(ConsoleSettings, self.parameters.values)
        self.access = resolve_access(self.settings)
        robot = load_robot()
        self.joint_names = list(robot.names)
        self.neutral = {n: float(a) for n, a in zip(robot.names, robot.neutral_rad, strict=True)}
        self._lock = threading.Lock()
        # the room's decoding, echo cancelling and JPEG encoding: in a thread of its own, started
        # with the server (the executor and this lock never wait on that work)
        self.room = RoomWorker(self._to_pages, lambda: bool(self.server.sessions))
        self.latency = VoiceLatency()
        self.commanded: dict[str, float] | None = None
        self.measured: dict[str, float] | None = None
        self.measured_s = -1e9
        self.command_source = ""
        self.stop_state: bool | None = None
        self.enable_state: bool | None = None
        self.health: dict[str, tuple[int, str, float]] = {}
        self.chunks_published = 0
        self.talking = False
        self.camera = FeedWatch(f"{self.get_namespace().rstrip('/')}/{topics.CAMERA_IMAGE}")
        self.picture_s = -1e9  # when the last picture was handed over for encoding (monotonic)
        self.microphones_s = -1e9  # when the robot's microphones last arrived (monotonic)
        voice_node = self.settings.voice_node
        if not voice_node.startswith("/"):
            voice_node = f"{self.get_namespace().rstrip('/')}/{voice_node}"
        self.voice_status_name = status_name(voice_node)
        self.voice_values: dict[str, str] | None = None  # the voice node's last /diagnostics
        self.voice_heard_s = -1e9

        self.audio_pub = self.create_publisher(AudioData, topics.AUDIO, AUDIO_PUBLISH_QOS)
        self.info_pub = self.create_publisher(AudioInfo, topics.AUDIO_INFO, LATCHED_QOS)
        self.stop_pub = self.create_publisher(Bool, topics.STOP, LATCHED_QOS)
        self.emergency_stop: Client[Any, Any] = self.create_client(Trigger, topics.EMERGENCY_STOP)
        self.stops_confirmed = 0  # the filter's answers to the stops asked for
        self.stops_unconfirmed = 0  # refused, or no filter served the service
        self.enable_pub = self.create_publisher(Bool, topics.ENABLE, LATCHED_QOS)
        self.publish_audio_info()
        self.create_timer(AUDIO_INFO_PERIOD_S, self.guarded(self.publish_audio_info))

        bounded, guarded = self.create_bounded_subscription, self.guarded
        bounded(
            JointAnglesWithSpeed,
            topics.JOINT_ANGLES,
            self.on_joint_angles,
            LISTEN_QOS,
            MAX_JOINT_STATE_BYTES,
        )
        bounded(
            JointState,
            topics.COMMANDED_JOINT_STATES,
            self.on_commanded_joint_states,
            LISTEN_QOS,
            MAX_JOINT_STATE_BYTES,
        )
        bounded(
            JointState,
            topics.JOINT_STATES,
            self.on_measured,
            qos_profile_sensor_data,
            MAX_JOINT_STATE_BYTES,
        )
        bounded(
            DiagnosticArray,
            topics.DIAGNOSTICS,
            self.on_diagnostics,
            LISTEN_QOS,
            MAX_DIAGNOSTICS_BYTES,
        )
        # Only the arrival time matters: the message is never decoded.
        self.create_subscription(
            JointTrajectory, topics.RAW_TRAJECTORY, guarded(self.on_raw), LISTEN_QOS, raw=True
        )
        bounded(Image, topics.CAMERA_IMAGE, self.on_camera, CAMERA_QOS, MAX_IMAGE_BYTES)
        bounded(
            AudioBuffer,
            topics.ROBOT_MICROPHONES,
            self.on_microphones,
            LISTEN_QOS,
            MAX_MICROPHONE_BYTES,
        )
        self.create_subscription(Bool, topics.STOP, guarded(self.on_stop), LATCHED_QOS)
        self.create_subscription(Bool, topics.ENABLE, guarded(self.on_enable), LATCHED_QOS)

        filter_node, inference = self.settings.filter_node, self.settings.inference_node
        self.filter_style = KeptParameters(
            self,
            filter_node,
            STYLE_FIELDS,
            ParameterType.PARAMETER_DOUBLE,
            "style",
            f"{filter_node}'s parameter service is not available",
            keep_own=True,
        )
        self.inference_model = KeptParameters(
            self,
            inference,
            ["model_path"],
            ParameterType.PARAMETER_STRING,
            "model",
            f"{inference}'s parameter service is not available: the model was not changed",
            keep_own=True,
        )
        self.voice_mute = KeptParameters(
            self,
            self.settings.voice_node,
            ["muted"],
            ParameterType.PARAMETER_BOOL,
            "mute",
            f"{self.settings.voice_node}'s parameter service is not available "
            "(no voice out: start the console with --voice-out)",
        )

        self.server = ConsoleServer(
            self.settings,
            self.access,
            self,
            web_dir=share_path("web", "dist"),
            urdf_path=share_path("urdf", "pepper.urdf"),
            log=self._log,
        )
        self.server_thread = ServerThread(self.server)
        port = self.server_thread.start()
        self.room.start()
        if not self.server.built:
            self.get_logger().warning(
                f"the console's front end is not built ({share_path('web', 'dist')} has no "
                "index.html): install Node.js and npm and run `make setup`; the page says so"
            )
        address = (
            f"operator console: open {self.access.url(port)} and press Talk "
            f"({'token required' if self.access.token else 'no token: this machine only'})"
        )
        self.get_logger().info(address)
        to_terminal(f"[{self.get_name()}] {address}")  # also when the log goes to a file

    def _log(self, level: str, message: str) -> None:
        # rclpy refuses two severities from one line of code: one call each
        if level == "warning":
            self.get_logger().warning(message)
        else:
            self.get_logger().info(message)

    def destroy_node(self) -> None:
        """Stop the room's thread and the server (pages are told) before the node goes."""
        room: RoomWorker | None = getattr(self, "room", None)  # a half-built node has none
        if room is not None:
            room.stop()
        if self.server_thread is not None:
            self.server_thread.stop()
        super().destroy_node()

    def publish_diagnostics(self) -> None:
        """The heartbeat, after the room's thread's bad input and failures are reported."""
        for problem in self.room.take_problems():
            name = f"on_{problem.what}"
            self.report_failure(name, problem.message, problem.refused, problem.trace)
        super().publish_diagnostics()

    # --- to the graph (called from the server's thread) ------------------------------------------

    def publish_audio_info(self) -> None:
        """Latch the format of the audio, as audio_capture does: 16 kHz mono S16LE wave."""
        self.info_pub.publish(AudioInfo(**S16LE_MONO_16K.audio_info_fields()))

    def publish_audio(self, frame: AudioFrame, received_s: float) -> None:
        """Publish one chunk of the floor holder's voice."""
        self.audio_pub.publish(AudioData(data=frame.pcm))
        published_s = time.time()
        voice = np.frombuffer(frame.pcm, dtype="<i2").astype(np.float32) / 32768.0
        self.room.voice(voice, time.monotonic())  # for the echo canceller, in the room's thread
        with self._lock:
            self.chunks_published += 1
            self.latency.chunk_published(frame.stamp_ms * 1e-3, received_s, published_s)

    def start_talk(self) -> None:
        """A talker got the floor: chunks in flight before belong to nobody."""
        with self._lock:
            self.talking = True
            self.latency.reset()

    def end_talk(self) -> None:
        """No more audio: the filter's watchdog and silence timeout bring the robot to rest."""
        with self._lock:
            self.talking = False

    def set_stop(self, on: bool) -> None:
        """Publish the emergency stop (latched); a stop is also asked for by the filter's service.

        The latched topic keeps the stop for a filter that starts later and is shown by every
        console; the service (``emergency_stop``) is a stop alone, which no flood of
        ``stop: false`` on the topic can displace where the middleware filters no content
        (Jazzy, Humble). Its answers are counted (``stops_confirmed``), as are presses that
        found no filter serving it (``stops_unconfirmed``).
        """
        self.stop_pub.publish(Bool(data=on))
        if not on:
            return
        if not self.emergency_stop.service_is_ready():
            with self._lock:
                self.stops_unconfirmed += 1
            return
        self.emergency_stop.call_async(Trigger.Request()).add_done_callback(self._stop_answered)

    def _stop_answered(self, future: Future[Any]) -> None:
        """The filter's answer to a stop asked for: confirmed, or counted as not."""
        response = future.result()
        with self._lock:
            if response is not None and response.success:
                self.stops_confirmed += 1
            else:
                self.stops_unconfirmed += 1

    def set_enable(self, on: bool) -> None:
        """Publish enable (latched)."""
        self.enable_pub.publish(Bool(data=on))

    def set_style(self, settings: dict[str, float] | None) -> None:
        """Set the filter's live style parameters named in ``settings``; None: restore.

        A learned style, a preset or the page's sliders (size and tempo per part, where the
        hands rest and how high they go), kept in force (:class:`KeptParameters`). Before the
        first change, the filter's own style parameters are read and kept, so that going back
        restores the style the graph was started with (a preset of the launch file, say), not
        the identity.
        """
        if settings is None:
            self.filter_style.restore()
        else:
            self.filter_style.choose(
                {name: float(settings[name]) for name in STYLE_FIELDS if name in settings}
            )

    def set_model(self, folder: str | None, fallback: dict[str, float] | None = None) -> None:
        """Set the inference node's ``model_path`` to ``folder``; None: restore its own.

        Before the first change its own ``model_path`` is read and kept, so that going back
        restores the model the graph was started with; the model chosen is kept in force (a
        restarted inference node is set again). The node checks the model and blends it in; a
        refusal (its reason) is shown in the page, and ``fallback``, when given, becomes the
        filter's style (the style fitted to the model that keeps running).
        """
        if folder is None:
            self.inference_model.restore()
            return
        otherwise = None if fallback is None else (lambda: self.set_style(fallback))
        self.inference_model.choose({"model_path": folder}, otherwise)

    def set_voice_muted(self, on: bool) -> None:
        """Set the voice node's ``muted`` to the operator's choice (kept in force)."""
        self.voice_mute.choose({"muted": on})

    # --- from the graph ---------------------------------------------------------------------------

    def on_raw(self, _data: bytes) -> None:
        """A raw pose message arrived: pair it with the chunk that caused it."""
        now = time.time()
        with self._lock:
            self.latency.raw_arrived(now)

    def _command(self, names: list[str], angles: list[float], stamp: Any, source: str) -> None:
        now = time.time()
        pose = {n: float(a) for n, a in zip(names, angles, strict=False) if math.isfinite(a)}
        with self._lock:
            if source == "joint_angles" or self.command_source != "joint_angles":
                self.commanded, self.command_source = pose, source
            if source == self.command_source:
                self.latency.command_arrived(stamp_s(stamp), now)

    def on_joint_angles(self, msg: JointAnglesWithSpeed) -> None:
        """A command to naoqi_driver: the pose shown and the end of a latency."""
        self._command(
            list(msg.joint_names), list(msg.joint_angles), msg.header.stamp, "joint_angles"
        )

    def on_commanded_joint_states(self, msg: JointState) -> None:
        """The commanded pose (used where joint_angles is off)."""
        self._command(
            list(msg.name), list(msg.position), msg.header.stamp, "commanded_joint_states"
        )

    def on_measured(self, msg: JointState) -> None:
        """The robot's measured pose, drawn as a ghost."""
        pairs = zip(msg.name, msg.position, strict=False)
        pose = {name: float(p) for name, p in pairs if math.isfinite(p)}  # NaN: not measured
        with self._lock:
            self.measured, self.measured_s = pose, time.monotonic()

    def on_stop(self, msg: Bool) -> None:
        """The latched stop, from anyone."""
        with self._lock:
            self.stop_state = bool(msg.data)

    def on_enable(self, msg: Bool) -> None:
        """The latched enable, from anyone."""
        with self._lock:
            self.enable_state = bool(msg.data)

    def on_diagnostics(self, msg: DiagnosticArray) -> None:
        """Keep each status's level and message for the page's health panel.

        Of the voice node's status, the values the page shows of the voice are kept too.
        """
        now = time.monotonic()
        with self._lock:
            for status in msg.status[:MAX_HEALTH_STATUSES]:
                if status.name == self.voice_status_name:
                    self.voice_values = {
                        kv.key: kv.value[:MAX_HEALTH_MESSAGE_CHARS]
                        for kv in status.values
                        if kv.key in VOICE_KEYS
                    }
                    self.voice_heard_s = now
                if status.name in self.health or len(self.health) < MAX_HEALTH_STATUSES:
                    self.health[status.name[:80]] = (
                        _level(status.level),
                        status.message[:MAX_HEALTH_MESSAGE_CHARS],
                        now,
                    )

    def _to_pages(self, item: RoomItem) -> None:
        """Hand one picture or block of sound to the server's loop for every identified page.

        Called in the room's thread.
        """
        if self.server_thread is None:
            return
        with contextlib.suppress(RuntimeError):  # the loop closed: the node is going
            self.server_thread.loop.call_soon_threadsafe(self.server.offer_room, item)

    def on_camera(self, msg: Image) -> None:
        """The robot's camera: to the room's thread for JPEG, at most MAX_PICTURES_PER_S."""
        now = time.monotonic()
        with self._lock:
            self.camera.arrived(now, time.time())
        if now - self.picture_s < 1.0 / MAX_PICTURES_PER_S or not self.server.sessions:
            return
        self.picture_s = now
        self.room.picture(
            Picture(
                int(msg.width),
                int(msg.height),
                str(msg.encoding),
                int(msg.step),
                bytes(msg.data),
                _taken_s(msg.header.stamp),
            )
        )

    def on_microphones(self, msg: AudioBuffer) -> None:
        """The robot's microphones: to the room's thread (16 kHz mono, echo removed, pages)."""
        self.microphones_s = time.monotonic()
        self.room.microphones(
            MicrophoneBlock(
                int(msg.frequency),
                tuple(int(c) for c in msg.channel_map),
                np.array(msg.data, dtype=np.int16),
                _taken_s(msg.header.stamp),
                self.microphones_s,
            )
        )

    # --- snapshots for the pages (called from the server's thread) -------------------------------

    def pose(self) -> dict[str, Any]:
        """The commanded pose and, while fresh, the measured one."""
        with self._lock:
            fresh = time.monotonic() - self.measured_s <= MEASURED_TIMEOUT_S
            return {"commanded": self.commanded, "measured": self.measured if fresh else None}

    def status(self) -> dict[str, Any]:
        """Stop, enable, the style parameters, health and latency for the pages."""
        now = time.monotonic()
        muted = (self.voice_mute.values or {}).get("muted")
        model_path = (self.inference_model.values or {}).get("model_path")
        problems = (self.filter_style.problem, self.inference_model.problem)
        with self._lock:
            for name in [n for n, (_, _, t) in self.health.items() if now - t > HEALTH_FORGET_S]:
                del self.health[name]
            health = [
                {
                    "name": name,
                    "level": level if now - heard <= STALE_AFTER_S else DiagnosticStatus.STALE[0],
                    "message": message if now - heard <= STALE_AFTER_S else "no heartbeat",
                }
                for name, (level, message, heard) in sorted(self.health.items())
            ]
            voice_age_s = now - self.voice_heard_s
            seen = RobotSeen(
                joint_states=now - self.measured_s <= MEASURED_TIMEOUT_S,
                microphones=now - self.microphones_s <= MICROPHONES_TIMEOUT_S,
                talked=self.chunks_published > 0,
            )
            voice = voice_view(
                self.voice_values if voice_age_s <= HEALTH_FORGET_S else None,
                None if muted is None else bool(muted),
                seen,
                self.voice_mute.problem,
                voice_age_s,
            )
            return {
                "stop": self.stop_state,
                "enable": self.enable_state,
                "style_values": self.filter_style.values,
                "style_problem": "; ".join(p for p in problems if p),
                "model_path": None if model_path is None else str(model_path),
                "health": health,
                "latency": self.latency.summary(),
                "voice": voice,
                "camera": self.camera.view(now),
            }

    # --- own diagnostics ---------------------------------------------------------------------

    def diagnostic_summary(self) -> tuple[bytes, str]:
        """Who holds the floor, how many operators are connected; WARN: the camera stopped."""
        holder = self.server.floor.holder_name
        operators = len(self.server.sessions)
        talk = f"{holder} is talking" if holder else "nobody is talking"
        address = self.access.url(self.server.port).split("#")[0]
        summary = f"serving {address}: {operators} operator(s), {talk}"
        with self._lock:
            camera = self.camera.problem(time.monotonic())
        if camera is not None:  # the robot's camera has stopped: the room's picture is frozen
            return DiagnosticStatus.WARN, f"{summary}; {camera}"
        return DiagnosticStatus.OK, summary

    def diagnostic_values(self) -> dict[str, object]:
        """Operators, audio published, refusals and the voice-to-command latency."""
        with self._lock:
            latency = self.latency.summary()
            chunks = self.chunks_published
            age = self.camera.age_s(time.monotonic())
            camera = {
                "camera_frames": self.camera.frames,
                "camera_stops": self.camera.stops,
                "camera_frame_age_s": "none" if age is None else f"{age:.1f}",
            }
        return {
            "operators": len(self.server.sessions),
            "floor": self.server.floor.holder_name or "free",
            "chunks_published": chunks,
            "refused_connections": self.server.refused_connections,
            "refused_frames": self.server.refused_frames,
            "room_watchers": self.server.watchers,
            "room_level_dbfs": f"{self.room.level_dbfs:.1f}",
            "echo_delay_s": f"{self.room.echo_delay_s:.3f}",
            "room_sound_blocks": self.room.blocks,
            "room_pictures_encoded": self.room.pictures,
            "room_sounds_dropped_behind": self.room.sounds_dropped,
            "room_pictures_dropped_behind": self.room.pictures_dropped,
            "room_voice_dropped_behind": self.room.voice_dropped,
            **camera,
            **self._room_counts(),
            **self._front_door_values(),
            **{f"latency_{key}": value for key, value in latency.items()},
        }

    def _room_counts(self) -> dict[str, object]:
        """Pictures and blocks of sound sent to the pages and dropped for slow ones."""
        counts: dict[str, object] = {}
        for what in ("sent", "dropped"):
            for kind in ("picture", "sound"):
                counts[f"room_{kind}s_{what}"] = sum(
                    getattr(session.room, what)[kind]
                    for session in list(self.server.sessions.values())
                )
        return counts

    def _front_door_values(self) -> dict[str, object]:
        """Wrong tokens, and who holds the stop (an absent holder marked as such)."""
        holders = [p.name if p.present else f"{p.name} (left)" for p in self.server.stops.presses]
        return {
            "wrong_tokens": self.server.tokens.wrong_tokens,
            "stop_held_by": ", ".join(holders) or "nobody",
            "stops_confirmed": self.stops_confirmed,
            "stops_unconfirmed": self.stops_unconfirmed,
        }


def main(args: list[str] | None = None) -> None:
    """Run the node until shutdown."""
    run_node(ConsoleNode, "console_node", args)


if __name__ == "__main__":
    main()

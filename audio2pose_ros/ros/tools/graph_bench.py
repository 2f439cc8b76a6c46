"""``audio2pose bench --graph``: latency, CPU, memory and start-up of the live node graph.

The three nodes run as processes (as ``audio2pose run`` starts them) and this process plays
audio_capture: real speech in 10 ms AudioData chunks (160 samples) in real time. After an
aligned warm-up every chunk completes exactly one feature frame, so chunk j causes raw pose j.

Latency is measured message by message. The filter runs with smoothing off and limits wide
open for the measurement (its timing is the same with any smoothing: Kalman and low-pass are
causal one-step filters; their *signal* lag is a property of the filter, shown by
``audio2pose plot-filter``), so the /joint_angles command that carries raw pose j equals it and
identifies it. End-to-end latency of chunk j = arrival of that command - publication of chunk j.
The feature window's algorithmic delay (a 25 ms window is complete only with its last sample) is
outside this figure: it belongs to the features, not to the graph, and is the same in any
implementation.

CPU is read from /proc for each node process: ``cpu_ms_per_frame`` from the end of the warm-up
to the end of the run, and ``steady_cpu_ms_per_frame`` over the steady part only, from
:data:`STEADY_SKIP_S` after the stream starts until its last chunk (no start-up, no idle tail).
The graph runs as three processes (the default) or, with ``single_process``, as one
(:mod:`audio2pose_ros.ros.nodes.single_process`). :func:`targets` compares the figures with the
footprint targets in :data:`TARGETS`.
"""

from __future__ import annotations

import gc
import subprocess
import sys
import tempfile
import time
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml
from audio_common_msgs.msg import AudioData, AudioInfo
from diagnostic_msgs.msg import DiagnosticArray
from naoqi_bridge_msgs.msg import JointAnglesWithSpeed
from rclpy.node import Node
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros import topics
from audio2pose_ros.audio.pcm import S16LE_MONO_16K, encode_pcm
from audio2pose_ros.audio.wav import read_wav
from audio2pose_ros.checkpoints.format import feature_spec_of
from audio2pose_ros.data.bag import AUDIO_DATA_TYPE, AUDIO_INFO_TYPE, BagMessage
from audio2pose_ros.files import packaged_mapping
from audio2pose_ros.resources import bundled_speech_paths, default_checkpoint_path
from audio2pose_ros.robot.body import BodyModel
from audio2pose_ros.robot.description import load_robot
from audio2pose_ros.ros.player import (
    MessagePlayer,
    rclpy_session,
    silence_message,
    spin_until,
    warm_up,
)
from audio2pose_ros.ros.supervisor import SIM_NODE, GraphTimeoutError, node_graph
from audio2pose_ros.ros.tools.process_stats import cpu_s, rss_mb
from audio2pose_ros.ros.tools.relay_floor import EXECUTORS as RELAY_EXECUTORS
from audio2pose_ros.ros.tools.relay_floor import ROLES as RELAY_ROLES
from audio2pose_ros.timebase import FRAME_PERIOD_S, SAMPLE_RATE_HZ, SAMPLES_PER_FRAME

CHUNK_SAMPLES = SAMPLES_PER_FRAME  # one 10 ms frame step per chunk (seed 003 section 4.2.2)
MATCH_TOLERANCE_RAD = 1e-5  # float32 /joint_angles against float64 raw poses
STEADY_SKIP_S = 2.0  # steady-state CPU is read from this long after the stream starts
SINGLE_FLOOR = "relays in one process"  # the floor's name for the graph in one process
ROBOT_PERIOD_S = 0.02  # the bench's stand-in driver reports the pose at 50 Hz
ANSWER_TIMEOUT_S = 60.0  # the graph must command and answer audio this soon after the start
# Footprint targets: (figure, three-process target, single-process target, unit); at most.
TARGETS = (
    ("steady CPU of the node processes per 10 ms frame", 1.0, 0.5, "ms"),
    ("steady CPU against the bare rclpy floor", 0.8, 0.8, "x"),
    ("resident memory of the node processes", 250.0, 150.0, "MB"),
    ("first command after start", 1.5, 1.5, "s"),
    ("latency audio -> /joint_angles p99", 10.0, 10.0, "ms"),
)


@dataclass
class FloorFigures:
    """The bare rclpy relays of :mod:`audio2pose_ros.ros.tools.relay_floor` (ms per frame, MB)."""

    steady_cpu_ms_per_frame: dict[str, float]
    rss_mb: dict[str, float]
    executor: str = "plain"  # relay_floor.EXECUTORS: rclpy.spin's default, or the nodes' own


@dataclass
class GraphFigures:
    """What the graph benchmark measured (times in ms, memory in MB)."""

    mode: str  # "three-process" or "single-process"
    audio_s: float
    latency_raw_ms: np.ndarray  # chunk publication -> its raw pose at the filter's input
    latency_command_ms: np.ndarray  # chunk publication -> the /joint_angles command carrying it
    startup_first_command_s: float
    startup_first_response_s: float
    cpu_ms_per_frame: dict[str, float]
    steady_cpu_ms_per_frame: dict[str, float]
    rss_mb: dict[str, float]
    floor: FloorFigures | None = field(default=None)  # the relays, measured in the same run

    @property
    def floor_ratio(self) -> float:
        """Steady CPU of the nodes over the relay floor's (NaN without a floor)."""
        if self.floor is None:
            return float("nan")
        return sum(self.steady_cpu_ms_per_frame.values()) / max(
            sum(self.floor.steady_cpu_ms_per_frame.values()), 1e-9
        )


def _bench_params(directory: Path) -> Path:
    """Parameter and robot files: smoothing off, limits wide, so commands equal raw poses."""
    params = packaged_mapping("config", "pepper.yaml")
    robot = load_robot().to_dict()
    for joint in robot["joints"]:
        joint["max_acceleration_rad_s2"] = 1e12  # braking bounds then cost < 1e-9 rad
        joint["max_velocity_rad_s"] = 1e12
    robot_file = directory / "robot.yaml"
    robot_file.write_text(yaml.safe_dump(robot), encoding="utf-8")
    params["/**"]["ros__parameters"]["robot_description"] = str(robot_file)
    params["motion_filter_node"]["ros__parameters"].update(
        smoothing="none",
        position_margin_rad=0.0,
        velocity_fraction=1.0,
        silence_timeout_s=1000.0,
        max_buffer_s=1.0,
        body_margin_m=0.0,  # the guard still runs, but changes only poses inside the body
        state_file=str(directory / "motion_filter_state.json"),  # not the user's saved pose
    )
    params_file = directory / "params.yaml"
    params_file.write_text(yaml.safe_dump(params), encoding="utf-8")
    return params_file


class _Player(Node):
    """Plays audio through the shared player and stamps raw poses and commands on arrival.

    It also stands in for the robot's driver: it reports the robot's pose on joint_states
    every :data:`ROBOT_PERIOD_S`, the neutral pose until a command comes, then the last
    command (a robot that follows at once), so the filter starts from a measured pose as it
    does beside naoqi_driver.
    """

    def __init__(self) -> None:
        super().__init__("audio2pose_graph_bench")
        robot = load_robot()
        self.robot_names = list(robot.names)
        self.robot_pose = [float(v) for v in robot.neutral_rad]
        self.joint_states = self.create_publisher(
            JointState, topics.absolute(topics.JOINT_STATES), 10
        )
        self.create_timer(ROBOT_PERIOD_S, self._report_pose)
        self.player = MessagePlayer(
            self,
            [
                (topics.absolute(topics.AUDIO), AUDIO_DATA_TYPE),
                (topics.absolute(topics.AUDIO_INFO), AUDIO_INFO_TYPE),
            ],
        )
        self.raw: list[tuple[float, np.ndarray]] = []
        self.commands: list[tuple[float, np.ndarray]] = []
        self.create_subscription(
            JointTrajectory, topics.absolute(topics.RAW_TRAJECTORY), self._on_raw, 1000
        )
        self.create_subscription(
            JointAnglesWithSpeed, topics.absolute(topics.JOINT_ANGLES), self._on_command, 1000
        )

    def _on_raw(self, msg: JointTrajectory) -> None:
        now = time.monotonic()
        self.raw += [(now, np.asarray(p.positions)) for p in msg.points]

    def _on_command(self, msg: JointAnglesWithSpeed) -> None:
        self.commands.append((time.monotonic(), np.asarray(msg.joint_angles, dtype=np.float64)))
        if list(msg.joint_names) == self.robot_names:
            self.robot_pose = [float(v) for v in msg.joint_angles]

    def _report_pose(self) -> None:
        msg = JointState(name=self.robot_names, position=self.robot_pose)
        msg.header.stamp = self.get_clock().now().to_msg()
        self.joint_states.publish(msg)


def _timed_out(what: str) -> GraphTimeoutError:
    """The error of a graph that did not answer within :data:`ANSWER_TIMEOUT_S`."""
    return GraphTimeoutError(
        f"{what} within {ANSWER_TIMEOUT_S:g} s of the start (see the node logs)"
    )


def _speech_chunks(
    speech_16k: np.ndarray, duration_s: float
) -> tuple[np.ndarray, list[BagMessage]]:
    """``duration_s`` of the speech (repeated) and its AudioData chunks of one frame step each.

    Chunk j is due j frame periods after the first, as a live capture delivers them.
    """
    audio = np.resize(speech_16k, int(duration_s * SAMPLE_RATE_HZ) // CHUNK_SAMPLES * CHUNK_SAMPLES)
    payload = encode_pcm(audio, S16LE_MONO_16K)
    step = 2 * CHUNK_SAMPLES
    chunks = [
        BagMessage(
            timestamp_ns=round(j * FRAME_PERIOD_S * 1e9),
            topic=topics.absolute(topics.AUDIO),
            msgtype=AUDIO_DATA_TYPE,
            data=serialize_message(AudioData(data=payload[offset : offset + step])),
        )
        for j, offset in enumerate(range(0, len(payload), step))
    ]
    return audio, chunks


def measure_graph(
    speech_16k: np.ndarray,
    duration_s: float = 60.0,
    single_process: bool = False,
    with_floor: bool = False,
    floor_executor: str = "plain",
) -> GraphFigures:
    """Run the graph on ``duration_s`` of ``speech_16k`` (repeated) and measure it.

    ``single_process`` runs the three nodes in one process instead of three. ``with_floor``
    then runs the bare rclpy relays on the same chunks, as as many processes as the nodes
    (:func:`measure_floor`, its relays in ``floor_executor``), so that both figures come from
    one run on one machine state.
    """
    audio, chunks = _speech_chunks(speech_16k, duration_s)
    audio_topic = topics.absolute(topics.AUDIO)
    with tempfile.TemporaryDirectory() as tmp, rclpy_session():
        player = _Player()
        launched = time.monotonic()
        with node_graph(
            _bench_params(Path(tmp)),
            log_dir=Path(tmp) / "logs",
            single_process=single_process,
        ) as graph:
            player.player.publishers[topics.absolute(topics.AUDIO_INFO)].publish(
                AudioInfo(**S16LE_MONO_16K.audio_info_fields())
            )
            deadline = launched + ANSWER_TIMEOUT_S
            if not spin_until(player, deadline, lambda: bool(player.commands)):
                raise _timed_out("no /joint_angles command")
            first_command = time.monotonic() - launched
            if not warm_up(
                player.player, audio_topic, lambda: bool(player.raw), deadline - time.monotonic()
            ):
                raise _timed_out("no raw pose for the audio played")
            first_response = time.monotonic() - launched
            silence = silence_message(audio_topic)
            for _ in range(3):  # at least one 25 ms window of warm-up, then let it drain
                player.player.publish(silence)
            spin_until(player, time.monotonic() + 0.5)
            player.raw.clear()
            player.commands.clear()
            pids = {n: p.pid for n, p in graph.processes.items()}
            sent, cpu, steady, steady_frames = _play_measured(player, chunks, pids)
            rss = {n: rss_mb(pid) for n, pid in pids.items()}
        player.destroy_node()

    n = min(len(sent), len(player.raw))
    latency_raw = np.array([player.raw[j][0] - sent[j] for j in range(n)]) * 1e3
    latency_command = []
    c = 0
    for j in range(n):  # commands carry raw poses in order; a skipped pose matches nothing
        pose = player.raw[j][1]
        window = player.commands[c : c + 100]
        match = next(
            (
                i
                for i, (_, command) in enumerate(window)
                if np.abs(command - pose).max() <= MATCH_TOLERANCE_RAD
            ),
            None,
        )
        if match is not None:
            latency_command.append((window[match][0] - sent[j]) * 1e3)
            c += match + 1
    return GraphFigures(
        mode="single-process" if single_process else "three-process",
        audio_s=len(audio) / SAMPLE_RATE_HZ,
        latency_raw_ms=latency_raw,
        latency_command_ms=np.array(latency_command),
        startup_first_command_s=first_command,
        startup_first_response_s=first_response,
        cpu_ms_per_frame={k: 1e3 * v / max(n, 1) for k, v in cpu.items()},
        steady_cpu_ms_per_frame={k: 1e3 * v / steady_frames for k, v in steady.items()},
        rss_mb=rss,
        floor=(
            measure_floor(speech_16k, duration_s, floor_executor, single_process)
            if with_floor
            else None
        ),
    )


def _play_measured(
    player: _Player, chunks: list[BagMessage], pids: dict[str, int]
) -> tuple[list[float], dict[str, float], dict[str, float], int]:
    """Play ``chunks`` in real time; CPU of each process over the run and its steady part.

    Returns the publication time of each chunk, each process's CPU time (s) from the start of
    the play to 1 s after its end, its CPU time in the steady part (from :data:`STEADY_SKIP_S`
    after the start to the last chunk) and the number of chunks in that part.
    """
    cpu_start = {n: cpu_s(pid) for n, pid in pids.items()}
    sent: list[float] = []
    steady_start: dict[str, float] = {}
    steady_from = 0
    play_start = time.monotonic()

    def stamp(_: BagMessage) -> None:
        nonlocal steady_from
        now = time.monotonic()
        if not steady_start and now - play_start >= STEADY_SKIP_S:
            steady_start.update({n: cpu_s(pid) for n, pid in pids.items()})
            steady_from = len(sent)
        sent.append(now)

    # This process stamps every chunk and every arrival: its own garbage collections (20 ms
    # and more over its thousands of messages) would stamp them late, which is not the graph's
    # latency. The nodes' own collections stay in the figures.
    gc.collect()
    gc.disable()
    try:
        player.player.play(chunks, on_publish=stamp)
    finally:
        gc.enable()
    steady = {n: cpu_s(pid) - steady_start.get(n, cpu_start[n]) for n, pid in pids.items()}
    steady_frames = max(len(sent) - steady_from, 1)
    spin_until(player, time.monotonic() + 1.0)
    cpu = {n: cpu_s(pid) - cpu_start[n] for n, pid in pids.items()}
    return sent, cpu, steady, steady_frames


def measure_floor(
    speech_16k: np.ndarray,
    duration_s: float = 60.0,
    executor: str = "plain",
    single_process: bool = False,
) -> FloorFigures:
    """The bare rclpy floor (:mod:`audio2pose_ros.ros.tools.relay_floor`) on the graph's input.

    Three relays with the graph's topology and QoS, spinning in ``executor`` (``plain``:
    rclpy.spin's default; ``node``: the nodes' own), play the same chunks as
    :func:`measure_graph`, measured the same way: steady CPU per frame and resident memory.
    They run as three processes, or with ``single_process`` in one process and one executor
    (:data:`SINGLE_FLOOR`), as the graph does.
    """
    if executor not in RELAY_EXECUTORS:
        raise ValueError(f"executor must be one of {RELAY_EXECUTORS}, got {executor!r}")
    _, chunks = _speech_chunks(speech_16k, duration_s)
    audio_topic = topics.absolute(topics.AUDIO)
    n_features = feature_spec_of(default_checkpoint_path()).dim
    n_joints = load_robot().n_joints
    module = [sys.executable, "-m", "audio2pose_ros.ros.tools.relay_floor"]
    with tempfile.TemporaryDirectory() as tmp, rclpy_session(), ExitStack() as stack:
        player = _Player()
        stack.callback(player.destroy_node)
        processes: dict[str, subprocess.Popen[bytes]] = {}
        groups = {SINGLE_FLOOR: RELAY_ROLES} if single_process else {r: (r,) for r in RELAY_ROLES}
        for name, roles in groups.items():
            log = stack.enter_context(open(Path(tmp) / f"{name}.log", "wb"))
            command = [*module, *roles, "--features", str(n_features), "--joints", str(n_joints)]
            command += ["--executor", executor]
            processes[name] = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)
            stack.callback(_stop, processes[name])
        deadline = time.monotonic() + ANSWER_TIMEOUT_S
        if not spin_until(player, deadline, lambda: bool(player.commands)):
            raise _timed_out("no /joint_angles command from the relay floor")
        if not warm_up(player.player, audio_topic, lambda: bool(player.raw), ANSWER_TIMEOUT_S):
            raise _timed_out("no raw pose from the relay floor")
        spin_until(player, time.monotonic() + 0.5)
        pids = {role: p.pid for role, p in processes.items()}
        _, _, steady, steady_frames = _play_measured(player, chunks, pids)
        rss = {role: rss_mb(pid) for role, pid in pids.items()}
    return FloorFigures(
        steady_cpu_ms_per_frame={k: 1e3 * v / steady_frames for k, v in steady.items()},
        rss_mb=rss,
        executor=executor,
    )


def _stop(process: subprocess.Popen[bytes]) -> None:
    """SIGTERM, then SIGKILL after 5 s."""
    process.terminate()
    try:
        process.wait(timeout=5.0)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()


def bundled_speech() -> np.ndarray:
    """All bundled speech clips, concatenated (24.7 s)."""
    return np.concatenate([read_wav(p)[0] for p in bundled_speech_paths()])


def latency_stats(values_ms: np.ndarray) -> dict[str, float]:
    """Count, median, 99th percentile and maximum of latencies in ms (``{"n": 0}`` if none)."""
    if not len(values_ms):
        return {"n": 0}
    return {
        "n": len(values_ms),
        "p50_ms": float(np.median(values_ms)),
        "p99_ms": float(np.percentile(values_ms, 99)),
        "max_ms": float(values_ms.max()),
    }


def report(figures: GraphFigures) -> dict[str, object]:
    """Summary statistics (also the ``--json`` output)."""
    return {
        "mode": figures.mode,
        "audio_s": figures.audio_s,
        "latency_audio_to_raw_pose": latency_stats(figures.latency_raw_ms),
        "latency_audio_to_joint_angles": latency_stats(figures.latency_command_ms),
        "startup_first_command_s": figures.startup_first_command_s,
        "startup_first_response_to_audio_s": figures.startup_first_response_s,
        "cpu_ms_per_frame": figures.cpu_ms_per_frame,
        "steady_cpu_ms_per_frame": figures.steady_cpu_ms_per_frame,
        "rss_mb": figures.rss_mb,
        "floor": None
        if figures.floor is None
        else {
            "steady_cpu_ms_per_frame": figures.floor.steady_cpu_ms_per_frame,
            "rss_mb": figures.floor.rss_mb,
            "executor": figures.floor.executor,
            "steady_cpu_ratio": figures.floor_ratio,
        },
        "targets": targets(figures),
    }


def targets(figures: GraphFigures) -> list[dict[str, object]]:
    """The footprint targets for the figures' mode: figure, value, target, unit, met."""
    single = figures.mode == "single-process"
    p99 = (
        float(np.percentile(figures.latency_command_ms, 99))
        if len(figures.latency_command_ms)
        else float("inf")
    )
    values = (
        sum(figures.steady_cpu_ms_per_frame.values()),
        figures.floor_ratio,
        sum(figures.rss_mb.values()),
        figures.startup_first_command_s,
        p99,
    )
    return [
        {
            "figure": name,
            "value": value,
            "target": single_target if single else three_target,
            "unit": unit,
            "met": bool(value <= (single_target if single else three_target)),
        }
        for (name, three_target, single_target, unit), value in zip(TARGETS, values, strict=True)
    ]


@dataclass
class SimTracking:
    """The graph against the simulated Pepper: commanded vs executed (degrees), self-collisions."""

    audio_s: float
    error_median_deg: float  # per measured pose, the largest joint error, then its median
    error_p95_deg: float
    executed_self_collision_steps: int  # the simulator's count (steps with an arm inside)
    measured_inside_body: int  # measured poses with clearance < 0 (our own check of the same)


class _SimObserver(_Player):
    """The bench player, also recording the simulated robot's measured joint states."""

    def __init__(self) -> None:
        super().__init__()
        self.measured: list[tuple[float, np.ndarray]] = []
        self.sim_values: dict[str, str] = {}
        names = load_robot().names
        self._names = names

        def on_state(msg: JointState) -> None:
            index = {name: i for i, name in enumerate(msg.name)}
            if all(name in index for name in names):
                position = np.array([msg.position[index[name]] for name in names])
                self.measured.append((time.monotonic(), position))

        def on_diagnostics(msg: DiagnosticArray) -> None:
            for status in msg.status:
                if status.name.endswith(SIM_NODE):
                    self.sim_values = {kv.key: kv.value for kv in status.values}

        self.create_subscription(JointState, topics.absolute(topics.JOINT_STATES), on_state, 1000)
        self.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, on_diagnostics, 100)


def measure_sim_tracking(speech_16k: np.ndarray, duration_s: float = 30.0) -> SimTracking:
    """Play ``duration_s`` of speech in real time through the graph and the simulated Pepper.

    The graph runs the package's parameters (real limits, the body guard); the simulated robot
    follows ``/joint_angles`` (:mod:`audio2pose_ros.robot.simulated_pepper`). Each measured
    joint state is compared with the command in force when it was received: the error is the
    robot's lag and speed, as the tracking watch of motion_filter_node sees it.
    """
    audio, chunks = _speech_chunks(speech_16k, duration_s)
    audio_topic = topics.absolute(topics.AUDIO)
    with tempfile.TemporaryDirectory() as tmp, rclpy_session():
        observer = _SimObserver()
        with node_graph(log_dir=Path(tmp) / "logs", sim=True):
            observer.player.publishers[topics.absolute(topics.AUDIO_INFO)].publish(
                AudioInfo(**S16LE_MONO_16K.audio_info_fields())
            )
            deadline = time.monotonic() + ANSWER_TIMEOUT_S
            if not warm_up(
                observer.player, audio_topic, lambda: bool(observer.raw), ANSWER_TIMEOUT_S
            ):
                raise _timed_out("no raw pose for the audio played")
            spin_until(observer, min(deadline, time.monotonic() + 0.5))
            observer.commands.clear()
            observer.measured.clear()
            observer.player.play(chunks)
            spin_until(observer, time.monotonic() + 1.5)  # the last diagnostics and states
        observer.destroy_node()
    command_t = np.array([c[0] for c in observer.commands])
    command_p = np.array([c[1] for c in observer.commands])
    measured = [m for m in observer.measured if len(command_t) and m[0] >= command_t[0]]
    if not measured:
        raise _timed_out("no measured joint states while commands came")
    stamps = np.array([m[0] for m in measured])
    positions = np.array([m[1] for m in measured])
    k = np.clip(np.searchsorted(command_t, stamps) - 1, 0, len(command_t) - 1)
    error = np.degrees(np.abs(positions - command_p[k]).max(axis=1))
    inside = int(np.count_nonzero(BodyModel.load().clearance(positions) < 0.0))
    return SimTracking(
        audio_s=len(audio) / SAMPLE_RATE_HZ,
        error_median_deg=float(np.median(error)),
        error_p95_deg=float(np.percentile(error, 95)),
        executed_self_collision_steps=int(observer.sim_values.get("self_collision_steps", -1)),
        measured_inside_body=inside,
    )

"""No flood of any input starves the timers a node's safety depends on.

Each case runs the real node process on its usual executor, floods one of its inputs from a
separate process publishing as fast as it can, and reads the outcome from what the node sends,
by the stamps the node put on it (so a probe that is itself slow to read does not matter),
against the CPU time the node's executor thread used meanwhile (read from /proc as the probe
listens). Once a paced timer's output falls due, the executor thread runs at most a quarter
period and the one callback running then before it; a starving node spends its CPU time on the
flood instead, up to seconds of it. A machine that is slow or busy gives the node less CPU
time, not more of it while an output is due, so the verdicts hold there too:

- never BEAT_LATE_CPU_S (0.25 s) of the executor's CPU time while a heartbeat is due;
- never STATE_LATE_CPU_S (40 ms) of it while one of the simulated Pepper's joint_states is due,
  under a flood of commands or a storm of parameter requests;
- the node served the flood (its counters grew) and counted what it dropped.

The rates on the wall clock (the fewest joint_states in a 1 s window, the longest heartbeat
silence) are printed for the record, not judged: a loaded machine lowers them with or without a
flood. The floods of node processes are marked long (``make test-long``): a flooder at full speed
beside the node takes a core, which would starve the suite's other real-time tests running
beside them; the paced timers' own tests run in ``make test``.
"""

from __future__ import annotations

import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

import flood_publisher
import numpy as np
import pytest
import rclpy
from audio_common_msgs.msg import AudioData, AudioInfo
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from executor_cpu import BEAT_LATE_CPU_S, ExecutorCpu
from naoqi_bridge_msgs.msg import JointAnglesWithSpeed
from rclpy.node import Node
from sensor_msgs.msg import JointState

from audio2pose_ros.audio.pcm import S16LE_MONO_16K, encode_pcm
from audio2pose_ros.ros.diagnosed_node import HEARTBEAT_PERIOD_S, DiagnosedNode
from audio2pose_ros.ros.messages import stamp_s
from audio2pose_ros.ros.nodes.audio_features_node import AudioFeaturesNode
from audio2pose_ros.ros.nodes.pepper_sim_node import STATE_PERIOD_S
from audio2pose_ros.ros.paced_timer import PacedTimer
from audio2pose_ros.ros.player import rclpy_session, spin_until
from audio2pose_ros.ros.supervisor import executable_command
from audio2pose_ros.ros.tools.process_stats import cpu_s
from audio2pose_ros.topics import DIAGNOSTICS, JOINT_STATES, absolute

pytestmark = pytest.mark.ros

FLOOD_S = 5.0
# While an output is due, the executor runs at most a quarter period and the callback running
# then (executor_cpu.py): with room for callbacks several times slower than here, the bounds on
# its CPU time meanwhile are (figures from 2 busy cores, the flooder at the tests' priority)
STATE_LATE_CPU_S = 0.04  # joint_states (20 ms): here at most 7 ms; starving: 16-540 ms
# and BEAT_LATE_CPU_S (0.25 s) for the heartbeat (0.5 s)
WINDOW_S = 1.0  # for the printed figure: the fewest joint_states in a 1 s window


@dataclass
class Heard:
    """What the flooded node sent, by the stamps it put on it, and the CPU time it had."""

    beats: list[tuple[float, DiagnosticStatus]] = field(default_factory=list)
    states: list[float] = field(default_factory=list)
    sent: int = 0
    first_s: float = 0.0  # wall clock, the flood's first and last message
    last_s: float = 0.0
    cpu: ExecutorCpu | None = None  # the node's executor thread through the flood
    process_cpu_s: float = 0.0  # the whole node process over the flood (for the record)

    @property
    def executor(self) -> ExecutorCpu:
        assert self.cpu is not None, "the flood never started"
        return self.cpu

    def beat_times(self) -> list[float]:
        return [t for t, _ in self.beats]

    def beats_inside(self) -> int:
        """Heartbeats stamped over the flood (from the first CPU reading to the last)."""
        return sum(self.executor.start_s < t < self.executor.end_s for t, _ in self.beats)

    def states_inside(self) -> int:
        """joint_states stamped over the flood (from the first CPU reading to the last)."""
        return sum(self.executor.start_s < t < self.executor.end_s for t in self.states)

    def longest_silence_s(self) -> float:
        """The longest time without a heartbeat during the flood (a figure, not a verdict)."""
        times = [t for t, _ in self.beats if self.first_s <= t <= self.last_s]
        return float(max(np.diff([self.first_s, *times, self.last_s])))

    def fewest_states_per_window(self) -> int:
        """The fewest joint_states in a 1 s window of the flood (a figure, not a verdict)."""
        stamps = np.array(sorted(self.states))
        starts = np.arange(self.first_s, self.last_s - WINDOW_S, 0.1)
        counts = np.searchsorted(stamps, starts + WINDOW_S) - np.searchsorted(stamps, starts)
        return int(counts.min())

    def figures(self) -> str:
        """What the node did with the CPU time it had, and its rates (for the record)."""
        late_beat_s = self.executor.most_after_due(self.beat_times(), HEARTBEAT_PERIOD_S)
        states = (
            f"{self.states_inside()} joint_states (at most "
            f"{self.executor.most_after_due(self.states, STATE_PERIOD_S) * 1e3:.0f} ms of CPU "
            f"after one was due; the fewest in a 1 s window: {self.fewest_states_per_window()}) "
            "and "
            if self.states
            else ""
        )
        return (
            f"{self.sent} messages in {self.last_s - self.first_s:.1f} s; the executor thread had "
            f"{self.executor.total_s():.2f} s of CPU (the process {self.process_cpu_s:.2f} s) and "
            f"sent {states}{self.beats_inside()} heartbeats (at most {late_beat_s:.2f} s of CPU "
            f"after one was due; the longest silence: {self.longest_silence_s():.2f} s)"
        )

    def value(self, key: str, status: DiagnosticStatus | None = None) -> int:
        status = status if status is not None else self.beats[-1][1]
        return int(float({kv.key: kv.value for kv in status.values}[key]))


def assert_heartbeat_kept(heard: Heard) -> None:
    """Never BEAT_LATE_CPU_S of the executor thread's CPU time after a heartbeat fell due.

    And one at least: a node the flood blocked uses no CPU time, and sends nothing either.
    """
    assert heard.beats_inside() > 0, heard.figures()
    late_cpu_s = heard.executor.most_after_due(heard.beat_times(), HEARTBEAT_PERIOD_S)
    assert late_cpu_s < BEAT_LATE_CPU_S, heard.figures()


def assert_states_kept(heard: Heard) -> None:
    """Never STATE_LATE_CPU_S of the executor thread's CPU time after a joint_state fell due."""
    assert heard.states_inside() > 0, heard.figures()
    late_cpu_s = heard.executor.most_after_due(heard.states, STATE_PERIOD_S)
    assert late_cpu_s < STATE_LATE_CPU_S, heard.figures()


def flood(tmp_path: Path, executable: str, kind: str, *ros_args: str) -> Heard:
    """Start ``executable``, flood it with ``kind`` (flood_publisher.py) for FLOOD_S, listen."""
    heard = Heard()
    log = (tmp_path / f"{executable}.log").open("w")
    command = [*executable_command(executable), *(["--ros-args", *ros_args] if ros_args else [])]
    node_process = subprocess.Popen(command, stdout=log, stderr=log)

    def on_diagnostics(array: DiagnosticArray) -> None:
        stamp = stamp_s(array.header.stamp)
        heard.beats.extend((stamp, s) for s in array.status if s.name.endswith(executable))

    with rclpy_session():
        probe = Node("flood_probe")
        probe.create_subscription(DiagnosticArray, DIAGNOSTICS, on_diagnostics, 1000)
        probe.create_subscription(
            JointState,
            absolute(JOINT_STATES),
            lambda m: heard.states.append(stamp_s(m.header.stamp)),
            1000,
        )
        flooder = None
        try:
            assert spin_until(probe, time.monotonic() + 60.0, lambda: bool(heard.beats)), "silent"
            flooder = flood_publisher.start(kind, FLOOD_S, log)
            assert flooder.stdout is not None
            assert flooder.stdout.readline().strip() == "ready"
            process_s = cpu_s(node_process.pid)
            heard.cpu = ExecutorCpu(node_process.pid)
            heard.cpu.read()
            while flooder.poll() is None:
                rclpy.spin_once(probe, timeout_sec=0.01)
                heard.cpu.read()
            heard.process_cpu_s = cpu_s(node_process.pid) - process_s
            words = flooder.stdout.read().split()
            assert len(words) == 4, f"the flooder failed (see {log.name}): {words}"
            heard.sent, heard.first_s, heard.last_s = int(words[1]), *map(float, words[2:4])
            spin_until(probe, time.monotonic() + 2.0)
        finally:
            if flooder is not None and flooder.poll() is None:
                flooder.kill()
            node_process.terminate()
            node_process.wait(20)
            probe.destroy_node()
    report = {kv.key: kv.value for kv in heard.beats[-1][1].values}
    print(f"{executable} flooded with {kind}: {heard.figures()}; last report {report}")
    return heard


@pytest.mark.long  # a real-time campaign: a flooder at full speed beside the node
def test_when_joint_angles_flood_the_simulated_pepper_expect_its_states_and_heartbeat(tmp_path):
    heard = flood(tmp_path, "pepper_sim_node", "joint_angles")
    assert heard.value("commands") > 0  # the flood was served
    assert_heartbeat_kept(heard)
    assert_states_kept(heard)


@pytest.mark.long  # a real-time campaign: a flooder at full speed beside the node
def test_when_one_byte_audio_chunks_flood_the_features_node_expect_its_heartbeat(tmp_path):
    heard = flood(tmp_path, "audio_features_node", "audio_bytes")
    chunks, decodes = heard.value("chunks_received"), heard.value("audio_decodes")
    assert chunks > 0  # the flood was served
    assert_heartbeat_kept(heard)
    # accumulated: one decode per 10 ms of audio (320 one-byte chunks), not one per chunk
    assert decodes * 10 <= chunks


@pytest.mark.long  # a real-time campaign: a flooder at full speed beside the node
def test_when_features_flood_the_inference_node_expect_its_heartbeat_and_counted_drops(
    tmp_path,
):
    heard = flood(tmp_path, "inference_node", "features")
    assert heard.value("frames_in") > 0  # the flood was served
    assert_heartbeat_kept(heard)
    # a second of frames a message, a hundred queued: those that waited over 0.5 s are dropped
    # unserved and counted, not computed seconds late
    assert heard.value("frames_behind_real_time") > 0


@pytest.mark.long  # a real-time campaign: a flooder at full speed beside the node
def test_when_set_parameters_requests_flood_the_simulated_pepper_expect_its_states(tmp_path):
    heard = flood(tmp_path, "pepper_sim_node", "set_parameters:pepper_sim_node")
    # Each request costs the node rclpy's take and answer; the timers run between requests.
    assert_heartbeat_kept(heard)
    assert_states_kept(heard)


def test_when_a_paced_timer_waits_behind_messages_expect_it_run_between_them_at_its_rate():
    clock = [0.0]
    runs: list[float] = []
    timer = PacedTimer(0.02, lambda: runs.append(clock[0]), clock=lambda: clock[0])

    # idle: the executor's timer event runs it, on time
    clock[0] = 0.02
    timer.on_timer()
    assert runs == [0.02]
    timer.run_if_overdue(0.021)  # between events, not overdue: nothing
    assert runs == [0.02]

    # flooded: the executor's event waits behind messages; between them the timer runs when
    # overdue, once per period, in phase, never in a burst
    for step in range(1, 187):  # a message every millisecond until 0.206 s
        clock[0] = 0.02 + step * 0.001
        timer.run_if_overdue(clock[0])
    assert len(runs) == 1 + 9  # one run per 20 ms
    assert max(np.diff(runs)) <= 0.02 * (1 + PacedTimer.OVERDUE_GRACE) + 0.001
    assert timer.runs_between_events == 9
    timer.on_timer()  # the late executor event finds this period served
    assert len(runs) == 10

    # a callback that overran several periods: one run, then the rate again (no catch-up)
    clock[0] += 0.1
    timer.run_if_overdue(clock[0])
    timer.run_if_overdue(clock[0])
    assert len(runs) == 11


def test_when_a_paced_timer_is_rescheduled_expect_its_new_phase_and_no_run_while_cancelled():
    clock = [0.0]
    runs: list[float] = []
    timer = PacedTimer(0.01, lambda: runs.append(clock[0]), clock=lambda: clock[0])

    # moved (the filter's tick after a pose's arrival): due 15 ms from now, not at its old time
    clock[0] = 0.004
    timer.schedule(0.015)
    timer.run_if_overdue(0.0126)  # past the old due time and its grace: nothing
    clock[0] = 0.0105
    timer.on_timer()  # a stale executor event, well before the new due time: skipped
    assert runs == []
    timer.run_if_overdue(0.0214)
    assert runs == []
    clock[0] = 0.0215
    timer.run_if_overdue(clock[0])  # the new due time (0.019) and its grace: runs
    assert runs == [0.0215]
    # then its period again, in phase with the new due time (next due 0.029)
    timer.run_if_overdue(0.0314)
    clock[0] = 0.0315
    timer.run_if_overdue(clock[0])
    assert runs == [0.0215, 0.0315]

    # cancelled (the filter's start-up decision once started): never runs, until rescheduled
    timer.cancel()
    clock[0] = 1.0
    timer.run_if_overdue(clock[0])
    timer.on_timer()
    assert len(runs) == 2
    timer.schedule(0.1, period_s=0.1)  # a new period too
    clock[0] = 1.1
    timer.on_timer()
    clock[0] = 1.2
    timer.on_timer()
    assert runs[2:] == [1.1, 1.2]


def test_when_commands_flood_a_coalescing_subscription_expect_the_newest_and_a_count():
    with rclpy_session():
        node = DiagnosedNode("coalescing_check")
        try:
            served: list[JointAnglesWithSpeed] = []
            latest = node.create_latest_subscription(
                JointAnglesWithSpeed, "/coalescing_check", served.append, 10, 1024
            )
            publisher = node.create_publisher(JointAnglesWithSpeed, "/coalescing_check", 10)
            big = JointAnglesWithSpeed(joint_names=["HeadYaw"] * 100, joint_angles=[0.0] * 100)
            publisher.publish(big)  # oversized: dropped before decoding
            angles = [0.1 * k for k in range(1, 8)]
            for angle in angles:
                publisher.publish(
                    JointAnglesWithSpeed(joint_names=["HeadYaw"], joint_angles=[angle], speed=0.5)
                )
            deadline = time.monotonic() + 30.0
            while not (served and served[-1].joint_angles[0] == pytest.approx(angles[-1])):
                assert time.monotonic() < deadline, "the newest command never came"
                for _ in range(3):  # several arrive between two steps
                    rclpy.spin_once(node, timeout_sec=0.01)
                latest.serve()  # as the simulation step does
            # each command was followed or counted as replaced: none lost silently, the newest
            # always followed, never an older one after a newer
            assert len(served) + latest.dropped == len(angles)
            followed = [m.joint_angles[0] for m in served]
            assert followed == sorted(followed)
            assert node.oversized_messages == 1
            assert node.latest_inputs == [latest]
        finally:
            node.destroy_node()


def test_when_audio_comes_in_one_byte_chunks_expect_the_features_of_whole_chunks(speech):
    pcm = encode_pcm(speech[:16000], S16LE_MONO_16K)  # 1 s of speech
    outputs = []
    for chunk_bytes in (len(pcm), 1):
        with rclpy_session():
            node = AudioFeaturesNode()
            try:
                frames: list[np.ndarray] = []
                node.features_sink = frames.append
                node.on_audio_info(AudioInfo(**S16LE_MONO_16K.audio_info_fields()))
                for start in range(0, len(pcm), chunk_bytes):
                    node.on_audio_data(AudioData(data=pcm[start : start + chunk_bytes]))
                node.flush_audio()
                outputs.append(np.concatenate(frames))
                assert node.input.chunks == -(-len(pcm) // chunk_bytes)  # every chunk counted
                # one decode per 10 ms of audio (320 bytes), not one per chunk
                assert node.audio_batches <= len(pcm) // 320 + 1
            finally:
                node.destroy_node()
    whole, bytewise = outputs
    np.testing.assert_array_equal(bytewise, whole)


@pytest.mark.long  # a real-time campaign: a flooder at full speed beside the node
def test_when_commands_flood_the_console_expect_its_heartbeat_and_the_newest_kept(tmp_path):
    """The console shows the commanded pose (and times each command for its latency figure): a
    flood of joint_angles, once the flooder's writer has matched the console's reader, must not
    silence its heartbeat, which runs between the messages when it is due."""
    heard = flood(tmp_path, "console_node", "joint_angles", "-p", "port:=0")
    assert heard.sent > 1000  # a flood, to a matched reader
    assert_heartbeat_kept(heard)
    assert heard.value("callback_errors") == 0


def test_when_a_paced_timer_is_overdue_inside_its_own_run_expect_no_second_run_within_it():
    """A callback that runs the overdue timers (a request served from a tick) does not re-run."""
    now = [0.0]
    depth: list[int] = []
    running = [0]

    def callback() -> None:
        running[0] += 1
        depth.append(running[0])
        now[0] += 1.0  # a slow run: the timer is overdue again before it returns
        timer.run_if_overdue(now[0])
        running[0] -= 1

    timer = PacedTimer(0.01, callback, clock=lambda: now[0])
    now[0] = 0.05
    timer.run_if_overdue(now[0])
    timer.on_timer()
    assert depth == [1, 1]  # two runs, one after the other, never one inside the other
    assert timer.runs_between_events == 1

"""A node flooded with messages keeps its heartbeat, and says what it could not serve.

rclpy's EventsExecutor serves events in arrival order: while messages come faster than a node
serves them, its heartbeat timer waits behind the backlog, and a supervisor kills a node that is
working (the memory soak saw this at 10x real time). The heartbeat is a paced timer, run between
callbacks when overdue, and a guarded callback that ends with the heartbeat long overdue sends
it with a warning (DiagnosedNode). The flooded node is judged by the CPU time its executor used
while its heartbeat was due (executor_cpu.py), not by the wall clock, which a busy machine
stretches.
"""

from __future__ import annotations

import subprocess
import time
from collections.abc import Callable

import numpy as np
import pytest
import rclpy
from audio_common_msgs.msg import AudioData, AudioInfo
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from executor_cpu import BEAT_LATE_CPU_S, ExecutorCpu
from rclpy.node import Node
from std_msgs.msg import Float32MultiArray

from audio2pose_ros.audio.pcm import S16LE_MONO_16K, encode_pcm
from audio2pose_ros.checkpoints.numpy_runtime import load_streaming_model
from audio2pose_ros.resources import default_checkpoint_path
from audio2pose_ros.ros.diagnosed_node import HEARTBEAT_OVERDUE_S, HEARTBEAT_PERIOD_S, DiagnosedNode
from audio2pose_ros.ros.messages import features_to_msg, stamp_s
from audio2pose_ros.ros.player import rclpy_session, spin_until
from audio2pose_ros.ros.qos import AUDIO_QOS, LATCHED_QOS, STREAM_QOS
from audio2pose_ros.ros.supervisor import executable_command
from audio2pose_ros.topics import AUDIO, AUDIO_INFO, DIAGNOSTICS, FEATURES, absolute

pytestmark = pytest.mark.ros

# every frame sent to inference_node is computed, lost on the way or dropped behind real time
FRAME_COUNTS = ("frames_in", "frames_lost", "frames_behind_real_time")
FLOOD_S = 8.0  # longer than a supervisor's RESTART_AFTER_S: the old node went silent throughout


@pytest.fixture
def node():
    with rclpy_session():
        node = DiagnosedNode("backlog_check")
        yield node
        node.destroy_node()


def test_when_a_callback_ends_with_the_heartbeat_overdue_expect_it_sent_with_a_warning(node):
    sent: list[DiagnosticArray] = []
    node.diagnostics_pub.publish = sent.append  # type: ignore[method-assign]
    served: list[bool] = []
    callback = node.guarded(served.append)

    # building the node took longer than the period: the first heartbeat comes, no warning
    node.last_heartbeat_s = time.monotonic() - 2 * HEARTBEAT_OVERDUE_S
    callback(True)
    (first,) = sent
    assert first.status[0].level == DiagnosticStatus.OK

    node.last_heartbeat_s = time.monotonic()
    callback(True)
    assert len(sent) == 1  # on time: the timer sends it

    node.last_heartbeat_s = time.monotonic() - 2 * HEARTBEAT_OVERDUE_S
    callback(True)
    beat = sent[-1]
    (status,) = beat.status
    assert status.level == DiagnosticStatus.WARN
    values = {kv.key: kv.value for kv in status.values}
    assert values["problem: falling behind"] == "1"
    assert "late" in status.message
    assert values["late_heartbeats"] == "1"
    assert time.monotonic() - node.last_heartbeat_s < HEARTBEAT_OVERDUE_S
    callback(True)
    assert len(sent) == 2  # just sent: not again
    assert served == [True] * 4


FRAMES_PER_MESSAGE = 20


def _features_flood(probe: Node) -> Callable[[], int]:
    """inference_node's input: 20 frames a message of plausible features, numbered as
    audio_features_node numbers them; returns the frames sent so far."""
    model = load_streaming_model(default_checkpoint_path())
    spec = model.features
    rng = np.random.default_rng(0)
    shape = (FRAMES_PER_MESSAGE, spec.dim)
    frames = model.normalizer.mean + rng.standard_normal(shape) * model.normalizer.std
    msg = features_to_msg(frames.astype(np.float32), f"{spec.kind}{spec.dim}", 0)
    publisher = probe.create_publisher(Float32MultiArray, absolute(FEATURES), STREAM_QOS)
    sent = [0]

    def send() -> int:
        msg.layout.dim[0].label = f"frames from {sent[0]}"
        publisher.publish(msg)
        sent[0] += FRAMES_PER_MESSAGE
        return sent[0]

    return send


def _audio_flood(probe: Node) -> Callable[[], int]:
    """audio_features_node's input: 0.1 s chunks of 16 kHz speech-level noise, after AudioInfo."""
    info = probe.create_publisher(AudioInfo, absolute(AUDIO_INFO), LATCHED_QOS)
    info.publish(AudioInfo(**S16LE_MONO_16K.audio_info_fields()))
    noise = np.random.default_rng(0).normal(0.0, 0.1, 1600).astype(np.float32)
    msg = AudioData(data=encode_pcm(noise, S16LE_MONO_16K))
    publisher = probe.create_publisher(AudioData, absolute(AUDIO), AUDIO_QOS)
    sent = [0]

    def send() -> int:
        publisher.publish(msg)
        sent[0] += 10
        return sent[0]

    return send


@pytest.mark.long  # a real-time campaign: a flooder at full speed beside the node
@pytest.mark.parametrize(
    ("executable", "flood", "served_key", "falls_behind"),
    [
        # reliable features, 8 ms a message: a backlog forms
        ("inference_node", _features_flood, "frames_in", True),
        # best-effort audio: the middleware drops what the node cannot take, so it seldom
        # falls behind (here never; a busy machine may differ)
        ("audio_features_node", _audio_flood, "frames_published", None),
    ],
)
def test_when_a_node_is_flooded_expect_heartbeats_throughout(
    tmp_path,
    executable: str,
    flood: Callable[[Node], Callable[[], int]],
    served_key: str,
    falls_behind: bool | None,
):
    """The real node process on its usual executor, fed as fast as one process can send."""
    log = (tmp_path / f"{executable}.log").open("w")
    process = subprocess.Popen([*executable_command(executable)], stderr=log, stdout=log)
    beats: list[tuple[float, DiagnosticStatus]] = []  # by the node's stamps (wall clock)
    executor = ExecutorCpu(process.pid)

    def on_diagnostics(array: DiagnosticArray) -> None:
        stamp = stamp_s(array.header.stamp)
        beats.extend((stamp, s) for s in array.status if s.name.endswith(executable))

    with rclpy_session():
        probe = Node("flood_probe")
        probe.create_subscription(DiagnosticArray, DIAGNOSTICS, on_diagnostics, 100)
        send = flood(probe)
        try:
            assert spin_until(probe, time.monotonic() + 60.0, lambda: bool(beats)), "never heard"
            start, flood_end = time.time(), time.monotonic() + FLOOD_S
            sent = 0
            executor.read()
            while time.monotonic() < flood_end:
                frames_sent = send()
                sent += 1
                rclpy.spin_once(probe, timeout_sec=0)
                executor.read()
            end = time.time()
            spin_until(probe, time.monotonic() + 1.0)
            if executable == "inference_node":
                # once it has caught up, one more message shows what was lost before it
                frames_sent = send()
                assert spin_until(
                    probe,
                    time.monotonic() + 10.0,
                    lambda: sum(_value(beats[-1][1], key) for key in FRAME_COUNTS) == frames_sent,
                ), f"sent {frames_sent} frames; last report {beats[-1][1].values}"
        finally:
            process.terminate()
            process.wait(20)
            probe.destroy_node()
    times = [start] + [t for t, _ in beats if start <= t <= end]
    longest_gap_s = max(np.diff([*times, end]))
    statuses = [s for t, s in beats if t >= start]
    served = max(_value(s, served_key) for s in statuses)
    late_cpu_s = executor.most_after_due([t for t, _ in beats], HEARTBEAT_PERIOD_S)
    figures = (
        f"{executable}: sent {sent} messages in {FLOOD_S} s; {served_key} {served}; "
        f"heartbeats {len(times) - 1}, at most {late_cpu_s:.2f} s of the executor's CPU time "
        f"(of {executor.total_s():.2f} s) after one was due; longest gap {longest_gap_s:.2f} s"
    )
    print(figures)
    assert served > 0
    # The heartbeat ran between the messages once due (executor_cpu.py), on a slow or busy
    # machine too; the longest gap (on the wall clock, where a restart would come after
    # RESTART_AFTER_S) is printed for the record.
    assert len(times) > 1, figures
    assert late_cpu_s < BEAT_LATE_CPU_S, figures
    behind_keys = {"problem: falling behind", "problem: behind real time"}
    behind = [s for s in statuses if behind_keys & {kv.key for kv in s.values}]
    if falls_behind:
        # every frame sent was served, reported lost or dropped behind real time (counted
        # above): no silent loss
        lost = [s for s in statuses if "problem: frames lost" in [kv.key for kv in s.values]]
        assert lost
        assert all(s.level == DiagnosticStatus.WARN for s in lost)
    assert all(s.level == DiagnosticStatus.WARN for s in behind)


def _value(status: DiagnosticStatus, key: str) -> int:
    return int({kv.key: kv.value for kv in status.values}[key])

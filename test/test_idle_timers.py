"""An idle node is woken only by the timers it needs: its heartbeat and, for the filter, its tick.

Each node runs in the executor its process uses; every rclpy timer's callback is counted while
the node is idle for a number of its own heartbeats or ticks (counts, not times). A timer that
has something to do only now and then (saving the filter's state, flushing accumulated audio,
logging parameter changes) is armed when there is something to do, and disarmed after.
"""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest
from audio_common_msgs.msg import AudioData, AudioInfo
from rclpy.parameter import Parameter
from std_msgs.msg import Bool

from audio2pose_ros.audio.pcm import S16LE_MONO_16K, encode_pcm
from audio2pose_ros.motion import state_file
from audio2pose_ros.motion.state_file import load_memory
from audio2pose_ros.ros.executor import EXECUTOR_ENV, create_executor
from audio2pose_ros.ros.nodes.audio_features_node import AudioFeaturesNode
from audio2pose_ros.ros.nodes.motion_filter_node import MotionFilterNode
from audio2pose_ros.ros.player import rclpy_session
from audio2pose_ros.ros.spin import spin_once

pytestmark = pytest.mark.ros
MAX_SPINS = 20000  # a bound against a hung node only


def count_timer_callbacks(node) -> Counter:
    """Wrap every rclpy timer of ``node``: the returned counter counts each one's callbacks."""
    calls: Counter = Counter()

    def counting(timer, callback):
        def counted():  # no parameter: rclpy passes a TimerInfo to a callback that takes one
            calls[timer] += 1
            return callback()

        return counted

    for timer in node.timers:
        timer.callback = counting(timer, timer.callback)
    return calls


@pytest.fixture(params=["events", "single_threaded"])
def executor_kind(request, monkeypatch):
    monkeypatch.setenv(EXECUTOR_ENV, request.param)
    return request.param


def spin_until(executor, node, done) -> None:
    for _ in range(MAX_SPINS):
        if done():
            return
        spin_once(executor, [node], timeout_s=0.05)
    raise AssertionError("the node never got there")


def test_when_the_started_filter_is_idle_expect_no_timer_but_its_tick_and_heartbeat(
    executor_kind, tmp_path, monkeypatch
):
    monkeypatch.setenv("ROS_HOME", str(tmp_path))
    state = tmp_path / "state.json"
    no_robot = ["-p", "start_without_measured_pose:=true"]
    with rclpy_session(["--ros-args", "-p", f"state_file:={state}", *no_robot]):
        node = MotionFilterNode(subscribe_graph=False)
        executor = create_executor()
        try:
            executor.add_node(node)
            node.on_startup_timeout()  # started (from neutral): the filter ticks
            paced = {timer.timer for timer in node.paced_timers}
            calls = count_timer_callbacks(node)
            ticks, beats = node.ticks, node.heartbeats
            spin_until(executor, node, lambda: node.heartbeats >= beats + 3)
            others = {t: n for t, n in calls.items() if t not in paced}
            print(f"{node.ticks - ticks} ticks, {node.heartbeats - beats} heartbeats; {others}")
            assert node.ticks - ticks >= 50  # over a second of 100 Hz ticks
            assert others == {}  # nothing else woke the node (saving ran at 10 Hz before)

            # a stop is saved at once, and one right after it within the spacing, from the tick
            # (then a spacing of 2 s: writing the first may take longer than 0.1 s on a busy
            # machine, and the second would be written at once)
            node.on_stop(Bool(data=True), {"source_timestamp": 0})
            assert load_memory(state, node.robot).stopped
            monkeypatch.setattr(state_file, "MIN_SAVE_SPACING_S", 2.0)
            node.on_stop(Bool(data=False), {"source_timestamp": 2**62})
            assert node.state.due  # within MIN_SAVE_SPACING_S of the last write: it waits
            # then handed to the writer thread by the tick
            spin_until(executor, node, lambda: not load_memory(state, node.robot).stopped)
            assert {t: n for t, n in calls.items() if t not in paced} == {}

            # parameter changes: the first is logged at once, the next ones within a second
            # gathered and logged by a timer armed for them, which then disarms
            log = node.parameters._log
            for gain in (0.5, 0.6, 0.7):
                node.set_parameters([Parameter("head_gain", Parameter.Type.DOUBLE, gain)])
            assert log.values == {"head_gain": 0.7}  # gathered
            assert not log.timer.is_canceled()
            spin_until(executor, node, lambda: not log.values)
            assert calls[log.timer] == 1
            assert log.timer.is_canceled()
        finally:
            executor.shutdown()
            node.destroy_node()


def test_when_the_features_node_is_idle_expect_no_flush_timer_until_audio_waits(
    executor_kind, speech
):
    with rclpy_session():
        node = AudioFeaturesNode()
        executor = create_executor()
        try:
            executor.add_node(node)
            node.on_audio_info(AudioInfo(**S16LE_MONO_16K.audio_info_fields()))
            paced = {timer.timer for timer in node.paced_timers}
            calls = count_timer_callbacks(node)
            beats = node.heartbeats
            spin_until(executor, node, lambda: node.heartbeats >= beats + 3)
            assert {t: n for t, n in calls.items() if t not in paced} == {}  # 50 Hz before

            frames: list[np.ndarray] = []
            node.features_sink = frames.append
            pcm = encode_pcm(speech[:80], S16LE_MONO_16K)  # 5 ms: short of a decode
            node.on_audio_data(AudioData(data=pcm))
            assert node.pending
            assert not node.flush_timer.is_canceled()  # armed by the chunk
            spin_until(executor, node, lambda: not node.pending)
            assert node.audio_batches == 1  # flushed by the timer
            assert calls[node.flush_timer] == 1
            assert node.flush_timer.is_canceled()  # and disarmed again
            beats = node.heartbeats
            spin_until(executor, node, lambda: node.heartbeats >= beats + 2)
            assert calls[node.flush_timer] == 1
        finally:
            executor.shutdown()
            node.destroy_node()

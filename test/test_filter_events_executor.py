"""The nodes' executor: rclpy's stock SingleThreadedExecutor by default, the EventsExecutor opt-in.

The EventsExecutor (``AUDIO2POSE_EXECUTOR=events``) serves events first come, first served, and
the messages one subscription event brings back to back: a plain timer waits behind all of them.
The filter's tick is a paced timer, run between messages when overdue, so the node keeps its
tick there too. The verdicts are counts of the node's own ticks at positions in the backlog, not
rates or times.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
import rclpy
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros.ros import executor as executors
from audio2pose_ros.ros import spin
from audio2pose_ros.ros.messages import trajectory_msg
from audio2pose_ros.ros.nodes import motion_filter_node, single_process
from audio2pose_ros.ros.nodes.motion_filter_node import MotionFilterNode
from audio2pose_ros.ros.player import rclpy_session
from audio2pose_ros.topics import RAW_TRAJECTORY

pytestmark = pytest.mark.ros
BACKLOG = 100  # raw_trajectory messages waiting at once (the filter's queue holds 100)
NAMESPACE = "/events_backlog"  # the filter's and the publisher's
POINTS = 200  # poses per message: max_points_per_message, each message costs its decoding


@pytest.fixture
def events_available():
    try:
        from rclpy.experimental.events_executor import EventsExecutor
    except ImportError:  # Humble
        pytest.skip("this rclpy has no EventsExecutor")
    return EventsExecutor


@pytest.mark.parametrize(
    ("main", "node_names"),
    [
        (motion_filter_node.main, ["motion_filter_node"]),
        (single_process.main, list(single_process.NODE_NAMES)),
    ],
    ids=["motion_filter_node", "single_process"],
)
def test_when_started_with_default_settings_expect_the_stock_single_threaded_executor(
    tmp_path, monkeypatch, main, node_names
):
    monkeypatch.delenv(executors.EXECUTOR_ENV, raising=False)
    monkeypatch.setenv("ROS_HOME", str(tmp_path))
    spun: list[tuple[object, list[str]]] = []

    def record(executor, nodes=(), until=None):
        spun.append((executor, [node.get_name() for node in nodes]))

    monkeypatch.setattr(spin, "spin_executor", record)
    main(["--ros-args", "-p", f"state_file:={tmp_path / 'state.json'}"])
    assert len(spun) == 1
    executor, names = spun[0]
    assert names == node_names
    assert type(executor) is rclpy.executors.SingleThreadedExecutor


def test_when_events_is_asked_for_expect_the_events_executor(events_available, monkeypatch):
    monkeypatch.setenv(executors.EXECUTOR_ENV, executors.EVENTS)
    with rclpy_session():
        assert type(executors.create_executor()).__name__ == events_available.__name__


@pytest.fixture
def started_filter(tmp_path, monkeypatch):
    """A started filter node and a publisher node, not yet added to an executor."""
    monkeypatch.setenv("ROS_HOME", str(tmp_path))
    monkeypatch.setenv(executors.EXECUTOR_ENV, executors.EVENTS)
    args = ["--ros-args", "-p", f"state_file:={tmp_path / 'state.json'}"]
    # in a namespace of its own: a raw_trajectory publisher left in the graph by another test
    # or process would make the filter refuse every raw pose (no message info here)
    args += ["-r", f"__ns:={NAMESPACE}"]
    with rclpy_session([*args, "-p", "start_without_measured_pose:=true"]):  # no robot here
        node = MotionFilterNode()
        publisher_node = rclpy.create_node("backlog_publisher")
        node.on_startup_timeout()  # started (from neutral): the filter ticks
        assert node.started
        yield node, publisher_node
        publisher_node.destroy_node()
        node.destroy_node()


def test_when_a_backlog_of_raw_trajectories_waits_expect_ticks_between_its_messages(
    events_available, started_filter, robot
):
    node, publisher_node = started_filter
    publisher = publisher_node.create_publisher(JointTrajectory, RAW_TRAJECTORY, BACKLOG)
    deadline = time.monotonic() + 30
    while not publisher.get_subscription_count():
        assert time.monotonic() < deadline, "the filter never subscribed"
        time.sleep(0.01)
    others = node.get_publishers_info_by_topic(f"{NAMESPACE}/{RAW_TRAJECTORY}")
    assert len(others) == 1, [f"{o.node_namespace}/{o.node_name}" for o in others]
    ticks_at: list[int] = []  # the raw messages the node had taken at each tick
    on_tick = node.on_tick
    node.on_tick = lambda: (ticks_at.append(node.input_messages), on_tick())[1]
    poses = np.tile(robot.neutral_rad, (POINTS, 1))
    stamp_ns = publisher_node.get_clock().now().nanoseconds
    for i in range(BACKLOG):  # stamped in order, inside the accepted stamp ages
        msg = trajectory_msg(robot.names, poses, 0.01)
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns + i * 1000, 10**9)
        publisher.publish(msg)
    time.sleep(0.5)  # all delivered before the executor looks: one event brings them all

    executor = executors.create_executor()
    assert type(executor).__name__ == events_available.__name__
    executor.add_node(node)
    deadline = time.monotonic() + 60
    while node.input_messages < BACKLOG:
        assert time.monotonic() < deadline, f"{node.input_messages} of {BACKLOG} messages came"
        spin.spin_once(executor, [node], timeout_s=0.1)
    during = [n for n in ticks_at if 1 < n < BACKLOG]
    print(f"ticks at these counts of messages taken: {ticks_at}")
    # A plain timer waits behind the whole event (one tick, on the first pose's arrival); the
    # paced tick runs between the messages.
    assert len(during) >= 2, ticks_at
    assert node.ticks == len(ticks_at)
    executor.shutdown()

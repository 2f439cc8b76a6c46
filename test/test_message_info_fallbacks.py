"""The nodes as Humble's rclpy runs them: callbacks without message info, QoS events elsewhere.

Humble's executors pass a subscription callback the message alone (its ``Subscription`` has no
``CallbackType``), and Kilted's EventsExecutor fails on a callback that takes the info, so there
the nodes subscribe with message-only callbacks (:mod:`audio2pose_ros.ros.subscriptions`). Here
Kilted's rclpy is made to behave that way (``RCLPY_PASSES_INFO`` false: every callback
message-only, over real DDS), and each thing a node reads from the info has its fallback
checked: the second raw_trajectory publisher told by the graph, a release timed by its arrival
(the first message of its topic never ends a hold kept from before the restart), a late features
message never dropped as late, the flood counters without sequence numbers. Humble's QoS event
classes live in ``rclpy.qos_event``: with ``rclpy.event_handler`` hidden, the nodes take them
from there. Verdicts are counts and states, not times.
"""

from __future__ import annotations

import importlib
import time

import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.serialization import serialize_message
from std_msgs.msg import Bool
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros.motion.state_file import FilterMemory, save_memory
from audio2pose_ros.ros import subscriptions
from audio2pose_ros.ros.messages import published_s, publisher_of, trajectory_msg
from audio2pose_ros.ros.nodes.motion_filter_node import MotionFilterNode
from audio2pose_ros.ros.player import rclpy_session
from audio2pose_ros.ros.qos import LATCHED_QOS, STREAM_QOS
from audio2pose_ros.ros.spin import spin_once
from audio2pose_ros.ros.subscriptions import LatestMessage, SequenceGaps, quiet_event_callbacks
from audio2pose_ros.topics import RAW_TRAJECTORY, STOP, absolute

pytestmark = pytest.mark.ros
WAIT_S = 60  # bounds a hung middleware only: no verdict on time


@pytest.fixture
def humble_callbacks(monkeypatch):
    """Every subscription made from now on is message-only, as on Humble."""
    monkeypatch.setattr(subscriptions, "RCLPY_PASSES_INFO", False)
    assert not subscriptions.message_info_delivered()


def start_filter(tmp_path, monkeypatch, memory: FilterMemory | None = None):
    monkeypatch.setenv("ROS_HOME", str(tmp_path))
    state = tmp_path / "state.json"
    if memory is not None:
        save_memory(state, memory)
    rclpy.init(args=["--ros-args", "-p", f"state_file:={state}"])
    node = MotionFilterNode()
    other = rclpy.create_node("fallback_publisher")
    executor = rclpy.executors.SingleThreadedExecutor()
    executor.add_node(node)
    executor.add_node(other)
    return node, other, executor


def spin_until(executor, node, condition) -> None:
    deadline = time.monotonic() + WAIT_S
    while not condition():
        assert time.monotonic() < deadline, "the condition never came"
        spin_once(executor, [node], timeout_s=0.05)


@pytest.fixture
def filter_without_info(humble_callbacks, tmp_path, monkeypatch):
    node, other, executor = start_filter(tmp_path, monkeypatch)
    yield node, other, executor
    executor.shutdown()
    other.destroy_node()
    node.destroy_node()
    rclpy.try_shutdown()


def test_when_callbacks_get_no_info_expect_raw_poses_taken_until_a_second_publisher_appears(
    filter_without_info, robot
):
    node, other, executor = filter_without_info
    node.on_startup_timeout()  # started (from neutral): raw poses are taken
    first = other.create_publisher(JointTrajectory, absolute(RAW_TRAJECTORY), STREAM_QOS)
    spin_until(executor, node, lambda: first.get_subscription_count() > 0)

    def send(publisher) -> None:
        msg = trajectory_msg(robot.names, robot.neutral_rad[None, :], 0.01)
        msg.header.stamp = other.get_clock().now().to_msg()
        publisher.publish(msg)

    for _ in range(5):
        send(first)
    spin_until(executor, node, lambda: node.input_messages >= 5)
    assert node.intake.dropped == 0

    second = other.create_publisher(JointTrajectory, absolute(RAW_TRAJECTORY), STREAM_QOS)
    spin_until(executor, node, lambda: node.count_publishers(RAW_TRAJECTORY) == 2)
    send(second)
    spin_until(executor, node, lambda: node.intake.dropped >= 1)
    assert "raw_second_source" in node.current_problems()
    other.destroy_publisher(second)
    spin_until(executor, node, lambda: node.count_publishers(RAW_TRAJECTORY) == 1)
    dropped = node.intake.dropped
    send(first)
    spin_until(executor, node, lambda: node.input_messages >= 6)
    assert node.intake.dropped == dropped  # one publisher again: taken


def test_when_callbacks_get_no_info_expect_stop_and_release_by_arrival(
    filter_without_info,
):
    node, other, executor = filter_without_info
    node.on_startup_timeout()
    stop = other.create_publisher(Bool, absolute(STOP), LATCHED_QOS)
    spin_until(executor, node, lambda: stop.get_subscription_count() > 0)
    stop.publish(Bool(data=True))
    spin_until(executor, node, lambda: node.filter.status.stopped)
    stop.publish(Bool(data=False))  # not the first message: timed by its arrival, after the stop
    spin_until(executor, node, lambda: not node.filter.status.stopped)


def test_when_a_kept_stop_meets_a_first_release_without_info_expect_it_asked_for_again(
    humble_callbacks, tmp_path, monkeypatch, robot
):
    """A latched ``stop: false`` of an older panel may be the first message: it releases nothing."""
    kept = FilterMemory(
        tuple(robot.names),
        tuple(float(v) for v in robot.neutral_rad),
        True,
        time.time() - 10.0,
        stopped_at_s=time.time() - 10.0,
    )
    node, other, executor = start_filter(tmp_path, monkeypatch, kept)
    try:
        assert node.filter.status.stopped
        stop = other.create_publisher(Bool, absolute(STOP), LATCHED_QOS)
        stop.publish(Bool(data=False))
        spin_until(executor, node, lambda: "stop_release_ignored" in node.current_problems())
        assert node.filter.status.stopped
        stop.publish(Bool(data=False))  # asked again: released
        spin_until(executor, node, lambda: not node.filter.status.stopped)
    finally:
        executor.shutdown()
        other.destroy_node()
        node.destroy_node()
        rclpy.try_shutdown()


def test_when_a_message_comes_without_info_expect_publisher_and_publication_time_unknown():
    assert published_s(None) is None
    assert publisher_of(None) is None
    jazzy_info = {"source_timestamp": 2_000_000_000, "publication_sequence_number": 7}
    assert publisher_of(jazzy_info) is None  # Jazzy: no gid
    assert published_s(jazzy_info) == pytest.approx(2.0)
    assert publisher_of({"publisher_gid": {"data": b"\x01\x02"}}) == b"\x01\x02"


def test_when_a_latest_input_gets_no_info_expect_the_newest_served_and_the_others_counted():
    served = []
    oversized = []
    latest = LatestMessage(Bool, served.append, 64, lambda n, cap: oversized.append(n))
    for value in (True, False, True):
        latest.receive(serialize_message(Bool(data=value)), None)
    latest.receive(b"\x00" * 100, None)  # over the cap: dropped undecoded
    latest.serve()
    latest.serve()  # nothing new: nothing served
    assert [m.data for m in served] == [True]
    assert (latest.superseded, latest.gaps.lost, latest.dropped) == (2, 0, 2)
    assert oversized == [100]


def test_when_sequence_numbers_come_without_a_gid_expect_no_gap_counted():
    gaps = SequenceGaps()
    for sequence in (1, 5, 9):  # two publishers' numbers cannot be told apart without the gid
        gaps.observe({"publication_sequence_number": sequence})
    assert gaps.lost == 0
    for sequence in (1, 5):
        gaps.observe({"publication_sequence_number": sequence, "publisher_gid": {"data": b"a"}})
    assert gaps.lost == 3


def test_when_raw_messages_of_the_one_source_are_lost_expect_them_counted_and_a_warn(
    tmp_path, monkeypatch
):
    """The raw reader is best effort: a gap in the one publisher's numbers (Jazzy: no gid)."""
    node, other, executor = start_filter(tmp_path, monkeypatch)
    try:
        message = trajectory_msg(node.robot.names, node.robot.neutral_rad[None, :], 0.01)
        for sequence in (1, 2, 5, 6):
            node.on_raw(message, {"publication_sequence_number": sequence})
        assert node.diagnostic_values()["raw_messages_lost"] == 2
        level, text, _ = node.current_problems()["raw_lost"]
        assert level == DiagnosticStatus.WARN
        assert "2 raw_trajectory messages lost" in text
    finally:
        executor.shutdown()
        other.destroy_node()
        node.destroy_node()
        rclpy.try_shutdown()


def test_when_rclpy_event_handler_is_missing_expect_the_qos_event_classes(monkeypatch):
    """Humble: the event callback classes come from rclpy.qos_event."""
    asked = []
    real_import = importlib.import_module

    def import_module(name: str):
        asked.append(name)
        if name == "rclpy.event_handler":
            raise ImportError(name)  # as on Humble
        return real_import(name)

    monkeypatch.setattr(subscriptions.importlib, "import_module", import_module)
    callbacks = quiet_event_callbacks("Subscription")
    assert asked == ["rclpy.event_handler", "rclpy.qos_event"]
    assert callbacks.use_default_callbacks is False
    with rclpy_session():
        node = rclpy.create_node("humble_events")
        node.create_subscription(
            Bool, "humble_events", lambda m: None, 1, event_callbacks=callbacks
        )
        node.destroy_node()


def test_when_an_inference_node_gets_no_info_expect_nothing_dropped_as_late():
    from audio2pose_ros.ros.nodes.inference_node import _waited_s

    assert _waited_s(None) == 0.0
    assert _waited_s({"received_timestamp": int((time.time() - 5.0) * 1e9)}) > 4.0


def test_when_info_is_delivered_expect_the_callback_to_take_two_parameters(monkeypatch):
    """rclpy tells the callbacks apart by their parameters: two for the info, one without."""
    import inspect

    got = []
    monkeypatch.setattr(subscriptions, "RCLPY_PASSES_INFO", True)
    monkeypatch.delenv("AUDIO2POSE_EXECUTOR", raising=False)
    with_info = subscriptions.info_callback(lambda m, i: got.append((m, i)))
    assert len(inspect.signature(with_info).parameters) == 2
    monkeypatch.setattr(subscriptions, "RCLPY_PASSES_INFO", False)
    without = subscriptions.info_callback(lambda m, i: got.append((m, i)))
    assert len(inspect.signature(without).parameters) == 1
    without("message")
    assert got == [("message", None)]


def test_when_rclpy_has_no_try_shutdown_expect_shutdown_once_and_no_error_after(monkeypatch):
    """Humble has only rclpy.shutdown, which raises on a context already down."""
    from audio2pose_ros.ros.executor import shutdown

    monkeypatch.delattr(rclpy, "try_shutdown")
    rclpy.init()
    shutdown()
    assert not rclpy.ok()
    shutdown()  # down already (Ctrl-C came first): nothing to do, no error

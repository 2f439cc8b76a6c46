"""A stop (a disable) published among a flood of releases from another process engages.

The filter reads ``stop`` and ``enable`` latched, at depth 1: a ``stop: true`` followed by
``stop: false`` faster than the executor takes them was replaced in that reader unseen, and the
robot never stopped. Here a separate process (flood_publisher.py) floods the releases while this
process's operator publishes one hold in the middle; the filter node, in this process, is not
spun until the flood is over (an executor that serves the topic as late as it likes), which
provoked the loss every time. Then it is spun until it has taken a release a second operator
published after the flood, and a few rounds more. The verdict is what the filter was told, in
order: the hold engaged once, whatever else came. Only where rclpy and the middleware filter
content (Kilted's rclpy, Fast DDS) does the filter read the topic's holds apart; elsewhere
(Jazzy, Humble) that test is skipped. A hold asked for by the filter's service
(``emergency_stop``, ``disable_motion``: what the console asks at every STOP) engages among the
same flood on every rclpy, each request once, and the answer says it is in force.
"""

from __future__ import annotations

import contextlib
import importlib.util
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import flood_publisher
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from std_msgs.msg import Bool
from std_srvs.srv import Trigger

from audio2pose_ros.ros.messages import published_s
from audio2pose_ros.ros.nodes.motion_filter_node import MotionFilterNode
from audio2pose_ros.ros.player import rclpy_session
from audio2pose_ros.ros.qos import LATCHED_QOS
from audio2pose_ros.topics import DISABLE_MOTION, EMERGENCY_STOP, ENABLE, STOP, absolute

pytestmark = pytest.mark.ros
needs_content_filters = pytest.mark.skipif(
    importlib.util.find_spec("rclpy.subscription_content_filter_options") is None,
    reason="this rclpy has no content filters: a hold on the topic can be displaced by a flood "
    "(doc/safety.md); the service's holds are tested below",
)
FLOOD_S = 2.0
WAIT_S = 60.0  # bounds a hung middleware or flooder only: no verdict on time
DRAIN_ROUNDS = 20  # executor rounds after the last release: a message already there is taken

# kind of flood, topic, the hold's value, the filter's setter, its argument for the hold, the
# service that asks for the hold alone
CASES = {
    "stop": ("stop_false", STOP, True, "set_stop", True, EMERGENCY_STOP),
    "disable": ("enable_true", ENABLE, False, "set_enabled", False, DISABLE_MOTION),
}


def _start_flood(kind: str, log_path: Path) -> tuple[subprocess.Popen[str], Callable[[], int]]:
    """The flooder, ready; and what waits for its end and gives how many it sent."""
    flooder = flood_publisher.start(kind, FLOOD_S, log_path.open("w"))
    assert flooder.stdout is not None
    assert flooder.stdout.readline().strip() == "ready", f"see {log_path}"

    def sent() -> int:
        words = flooder.communicate(timeout=WAIT_S)[0].split()
        assert words[:1] == ["sent"], f"the flooder failed: {words}"
        return int(words[1])

    return flooder, sent


@contextlib.contextmanager
def _filter_telling(
    setter: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> Iterator[tuple[MotionFilterNode, list[bool]]]:
    """A motion filter node of its own state file in a session, and what it tells its filter.

    What ``setter`` (``set_stop``, ``set_enabled``) was called with, in order.
    """
    monkeypatch.setenv("ROS_HOME", str(tmp_path))
    told: list[bool] = []
    with rclpy_session(["--ros-args", "-p", f"state_file:={tmp_path / 'state.json'}"]):
        node = MotionFilterNode()
        tell = getattr(node.filter, setter)
        monkeypatch.setattr(node.filter, setter, lambda value: (told.append(value), tell(value)))
        try:
            yield node, told
        finally:
            node.destroy_node()


@needs_content_filters
@pytest.mark.parametrize("case", list(CASES))
def test_when_releases_flood_and_one_hold_comes_in_the_middle_expect_it_engaged_once(
    case, tmp_path, monkeypatch
):
    kind, topic, hold, setter, engaged, _ = CASES[case]
    taken: list[tuple[bool, float]] = []  # the messages the node took: value, publication
    callback = "on_stop" if topic == STOP else "on_enable"
    take = getattr(MotionFilterNode, callback)

    def recorded(node: MotionFilterNode, msg: Bool, info) -> None:
        taken.append((msg.data, published_s(info) or time.time()))
        take(node, msg, info)

    monkeypatch.setattr(MotionFilterNode, callback, recorded)
    with _filter_telling(setter, tmp_path, monkeypatch) as (node, told):
        operator = rclpy.create_node("hold_operator")
        other = rclpy.create_node("later_operator")
        holds = operator.create_publisher(Bool, absolute(topic), LATCHED_QOS)
        releases = other.create_publisher(Bool, absolute(topic), LATCHED_QOS)
        flooder, sent = _start_flood(kind, tmp_path / "flooder.log")
        executor = SingleThreadedExecutor()
        try:
            deadline = time.monotonic() + WAIT_S
            while holds.get_subscription_count() == 0 or releases.get_subscription_count() == 0:
                assert time.monotonic() < deadline, "the filter never subscribed"
                time.sleep(0.01)
            time.sleep(FLOOD_S / 2)  # into the flood: where the hold comes, not a verdict
            holds.publish(Bool(data=hold))
            flooded = sent()
            after_flood_s = time.time()
            releases.publish(Bool(data=not hold))  # after every release of the flood

            executor.add_node(node)
            deadline = time.monotonic() + WAIT_S
            while not any(v != hold and at_s >= after_flood_s for v, at_s in taken):
                assert time.monotonic() < deadline, f"the later release never taken: {taken}"
                executor.spin_once(timeout_sec=0.05)
            for _ in range(DRAIN_ROUNDS):  # what the node's other reader holds, if anything
                executor.spin_once(timeout_sec=0.01)
        finally:
            if flooder.poll() is None:
                flooder.kill()
            executor.shutdown()
            other.destroy_node()
            operator.destroy_node()
    print(f"{case}: {flooded} releases flooded; the node took {len(taken)}, told the filter {told}")
    assert engaged in told, f"the {case} among {flooded} releases never reached the filter"
    deliveries = node.stop_deliveries if topic == STOP else node.disable_deliveries
    assert deliveries.engaged == 1


@pytest.mark.parametrize("case", list(CASES))
def test_when_releases_flood_and_the_service_asks_for_a_hold_expect_it_engaged_and_confirmed(
    case, tmp_path, monkeypatch
):
    kind, topic, hold, setter, engaged, service = CASES[case]
    with _filter_telling(setter, tmp_path, monkeypatch) as (node, told):
        operator = rclpy.create_node("hold_operator")
        client = operator.create_client(Trigger, absolute(service))
        releases = operator.create_publisher(Bool, absolute(topic), LATCHED_QOS)
        flooder, sent = _start_flood(kind, tmp_path / "flooder.log")
        executor = SingleThreadedExecutor()
        try:
            assert client.wait_for_service(timeout_sec=WAIT_S), "the filter serves no " + service
            time.sleep(FLOOD_S / 2)  # into the flood: where the request comes, not a verdict
            answer = client.call_async(Trigger.Request())
            flooded = sent()
            executor.add_node(node)
            executor.add_node(operator)
            executor.spin_until_future_complete(answer, timeout_sec=WAIT_S)
            assert answer.done(), f"the filter never answered {service}"
            response = answer.result()
            for _ in range(DRAIN_ROUNDS):  # the flood's newest release, if not taken yet
                executor.spin_once(timeout_sec=0.01)
            in_force = engaged in told[-1:]  # a release taken after the request ended it?
            releases.publish(Bool(data=not hold))  # published after the hold: releases it
            deadline = time.monotonic() + WAIT_S
            while told[-1:] != [not engaged]:
                assert time.monotonic() < deadline, f"the later release never taken: {told}"
                executor.spin_once(timeout_sec=0.05)
        finally:
            if flooder.poll() is None:
                flooder.kill()
            executor.shutdown()
            operator.destroy_node()
    print(f"{case}: {flooded} releases flooded; told the filter {told}; answer {response}")
    assert response.success, response.message
    assert in_force, f"a release published before the {case} asked for ended it: {told}"
    deliveries = node.stop_deliveries if topic == STOP else node.disable_deliveries
    assert deliveries.engaged == 1

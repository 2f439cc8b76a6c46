"""A stop (a disable) published among a flood of releases from another process engages.

The filter reads ``stop`` and ``enable`` latched, at depth 1: a ``stop: true`` followed by
``stop: false`` faster than the executor takes them was replaced in that reader unseen, and the
robot never stopped. Here a separate process (flood_publisher.py) floods the releases while this
process's operator publishes one hold in the middle; the filter node, in this process, is not
spun until the flood is over (an executor that serves the topic as late as it likes), which
provoked the loss every time. Then it is spun until it has taken a release a second operator
published after the flood, and a few rounds more. The verdict is what the filter was told, in
order: the hold engaged once, whatever else came. Only where rclpy and the middleware filter
content (Kilted's rclpy, Fast DDS) does the filter read the holds apart; elsewhere (Jazzy,
Humble) the test is skipped.
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import time
from pathlib import Path

import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from std_msgs.msg import Bool

from audio2pose_ros.ros.messages import published_s
from audio2pose_ros.ros.nodes.motion_filter_node import MotionFilterNode
from audio2pose_ros.ros.player import rclpy_session
from audio2pose_ros.ros.qos import LATCHED_QOS
from audio2pose_ros.topics import ENABLE, STOP, absolute

pytestmark = [
    pytest.mark.ros,
    pytest.mark.skipif(
        importlib.util.find_spec("rclpy.subscription_content_filter_options") is None,
        reason="this rclpy has no content filters: a hold can be displaced by a flood "
        "(doc/safety.md)",
    ),
]
FLOODER = Path(__file__).with_name("flood_publisher.py")
FLOOD_S = 2.0
WAIT_S = 60.0  # bounds a hung middleware or flooder only: no verdict on time
DRAIN_ROUNDS = 20  # executor rounds after the last release: a message already there is taken

# kind of flood, topic, the hold's value, the filter's setter, its argument for the hold
CASES = {
    "stop": ("stop_false", STOP, True, "set_stop", True),
    "disable": ("enable_true", ENABLE, False, "set_enabled", False),
}


@pytest.mark.parametrize("case", list(CASES))
def test_when_releases_flood_and_one_hold_comes_in_the_middle_expect_it_engaged_once(
    case, tmp_path, monkeypatch
):
    kind, topic, hold, setter, engaged = CASES[case]
    monkeypatch.setenv("ROS_HOME", str(tmp_path))
    taken: list[tuple[bool, float]] = []  # the messages the node took: value, publication
    callback = "on_stop" if topic == STOP else "on_enable"
    take = getattr(MotionFilterNode, callback)

    def recorded(node: MotionFilterNode, msg: Bool, info) -> None:
        taken.append((msg.data, published_s(info) or time.time()))
        take(node, msg, info)

    monkeypatch.setattr(MotionFilterNode, callback, recorded)
    told: list[bool] = []  # what the filter was told, in order
    args = ["--ros-args", "-p", f"state_file:={tmp_path / 'state.json'}"]
    with rclpy_session(args):
        node = MotionFilterNode()
        tell = getattr(node.filter, setter)
        monkeypatch.setattr(node.filter, setter, lambda value: (told.append(value), tell(value)))
        operator = rclpy.create_node("hold_operator")
        other = rclpy.create_node("later_operator")
        holds = operator.create_publisher(Bool, absolute(topic), LATCHED_QOS)
        releases = other.create_publisher(Bool, absolute(topic), LATCHED_QOS)
        log = (tmp_path / "flooder.log").open("w")
        flooder = subprocess.Popen(
            [sys.executable, str(FLOODER), kind, str(FLOOD_S)],
            stdout=subprocess.PIPE,
            stderr=log,
            text=True,
        )
        executor = SingleThreadedExecutor()
        try:
            assert flooder.stdout is not None
            assert flooder.stdout.readline().strip() == "ready", f"see {log.name}"
            deadline = time.monotonic() + WAIT_S
            while holds.get_subscription_count() == 0 or releases.get_subscription_count() == 0:
                assert time.monotonic() < deadline, "the filter never subscribed"
                time.sleep(0.01)
            time.sleep(FLOOD_S / 2)  # into the flood: where the hold comes, not a verdict
            holds.publish(Bool(data=hold))
            words = flooder.communicate(timeout=WAIT_S)[0].split()
            assert words[:1] == ["sent"], f"the flooder failed: {words}"
            flooded = int(words[1])
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
            node.destroy_node()
    print(f"{case}: {flooded} releases flooded; the node took {len(taken)}, told the filter {told}")
    assert engaged in told, f"the {case} among {flooded} releases never reached the filter"
    deliveries = node.stop_deliveries if topic == STOP else node.disable_deliveries
    assert deliveries.engaged == 1

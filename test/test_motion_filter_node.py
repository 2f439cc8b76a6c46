"""motion_filter_node over real DDS: watchdog glide, stop, head target, arms off.

The node runs as its own process (the real executable) with parameters on the command line, as a
launch file would pass them; this process plays inference_node's part (raw_trajectory) and the
robot's part (it reads joint_states). Only the robot is missing.
"""

from __future__ import annotations

import subprocess
import time

import numpy as np
import pytest
import rclpy
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros.cli.graph import executable_command
from audio2pose_ros.nodes.common import LATCHED_QOS, trajectory_msg

pytestmark = [pytest.mark.ros, pytest.mark.slow]
PERIOD = 0.01


class Driver(Node):
    def __init__(self) -> None:
        super().__init__("filter_test_driver")
        self.raw = self.create_publisher(JointTrajectory, "/raw_trajectory", 100)
        self.stop = self.create_publisher(Bool, "/stop", LATCHED_QOS)
        self.head = self.create_publisher(JointState, "/head_target", 10)
        self.states: list[tuple[float, np.ndarray]] = []
        self.create_subscription(JointState, "/joint_states", self.on_state, 1000)

    def on_state(self, msg: JointState) -> None:
        self.states.append((time.monotonic(), np.array(msg.position)))

    def spin_for(self, seconds: float, every=None) -> None:
        end, next_call = time.monotonic() + seconds, time.monotonic()
        while time.monotonic() < end:
            if every is not None and time.monotonic() >= next_call:
                every()
                next_call += PERIOD
            rclpy.spin_once(self, timeout_sec=0.002)

    def wait_for_node(self) -> None:
        end = time.monotonic() + 60
        while time.monotonic() < end and not (self.raw.get_subscription_count() and self.states):
            rclpy.spin_once(self, timeout_sec=0.05)
        assert self.states, "motion_filter_node did not come up"
        self.spin_for(0.5)


@pytest.fixture
def driver():
    with rclpy.init():
        node = Driver()
        yield node
        node.destroy_node()


@pytest.fixture
def filter_node(tmp_path):
    processes = []

    def start(**params: object) -> None:
        command = [*executable_command("motion_filter_node"), "--ros-args"]
        for key, value in {"joint_states_rate_hz": 100.0, **params}.items():
            command += ["-p", f"{key}:={value}"]
        log = (tmp_path / "motion_filter_node.log").open("w")
        processes.append(subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT))

    yield start
    for process in processes:
        process.terminate()
        process.wait(timeout=10)


def raised(robot) -> np.ndarray:
    pose = robot.neutral_rad.copy()
    pose[robot.names.index("LShoulderPitch")] -= 0.8
    pose[robot.names.index("RElbowRoll")] += 0.5
    pose[robot.names.index("HeadYaw")] += 0.4
    return pose


def send_poses(driver: Driver, robot, pose: np.ndarray):
    def send() -> None:
        driver.raw.publish(trajectory_msg(robot.names, pose[None, :], PERIOD))

    return send


def test_when_input_stops_expect_neutral_within_configured_time_at_bounded_velocity(
    driver, filter_node, robot
):
    filter_node(watchdog_timeout_s=0.3, neutral_glide_s=0.7, velocity_fraction=0.5)
    driver.wait_for_node()
    driver.spin_for(1.5, every=send_poses(driver, robot, raised(robot)))
    stopped_at = time.monotonic()
    driver.spin_for(2.0)

    times = np.array([t for t, _ in driver.states])
    poses = np.array([p for _, p in driver.states])
    speaking = poses[times < stopped_at][-1]
    assert np.abs(speaking - raised(robot)).max() < 0.05
    # Neutral within watchdog + glide (+ 0.2 s for DDS and timer jitter).
    due = times > stopped_at + 0.3 + 0.7 + 0.2
    np.testing.assert_allclose(poses[due], np.tile(robot.neutral_rad, (due.sum(), 1)), atol=2e-3)
    # Bounded velocity between consecutive states (with slack for message timing jitter).
    speed = np.abs(np.diff(poses, axis=0)) / np.maximum(np.diff(times)[:, None], PERIOD)
    assert np.all(speed <= 0.5 * robot.max_velocity_rad_s * 1.5)


def test_when_stop_requested_expect_motion_stops(driver, filter_node, robot):
    filter_node(stop_behaviour="hold")
    driver.wait_for_node()
    driver.spin_for(0.5, every=send_poses(driver, robot, robot.neutral_rad))
    driver.stop.publish(Bool(data=True))
    driver.spin_for(0.3, every=send_poses(driver, robot, robot.neutral_rad))
    driver.states.clear()
    driver.spin_for(1.0, every=send_poses(driver, robot, raised(robot)))  # ignored while stopped
    poses = np.array([p for _, p in driver.states])
    assert len(poses) > 50
    assert np.abs(poses - poses[0]).max() < 1e-6
    driver.stop.publish(Bool(data=False))
    driver.spin_for(1.5, every=send_poses(driver, robot, raised(robot)))
    assert np.abs(driver.states[-1][1] - raised(robot)).max() < 0.05  # released: moves again


def test_when_head_target_published_expect_head_follows_it(driver, filter_node, robot):
    filter_node(head_target_weight=1.0)
    driver.wait_for_node()

    def send() -> None:
        send_poses(driver, robot, robot.neutral_rad)()
        driver.head.publish(JointState(name=["HeadYaw", "HeadPitch"], position=[0.6, 0.1]))

    driver.spin_for(1.5, every=send)
    last = driver.states[-1][1]
    assert last[robot.names.index("HeadYaw")] == pytest.approx(0.6, abs=0.02)
    assert last[robot.names.index("HeadPitch")] == pytest.approx(0.1, abs=0.02)


def test_when_arms_disabled_expect_arms_stay_neutral(driver, filter_node, robot):
    filter_node(arms_gain=0.0)
    driver.wait_for_node()
    driver.spin_for(1.5, every=send_poses(driver, robot, raised(robot)))
    poses = np.array([p for _, p in driver.states])
    arms = robot.group_mask("arms")
    np.testing.assert_allclose(
        poses[:, arms], np.tile(robot.neutral_rad[arms], (len(poses), 1)), atol=1e-6
    )
    yaw = robot.names.index("HeadYaw")
    assert poses[-1, yaw] == pytest.approx(raised(robot)[yaw], abs=0.05)  # the head still moves

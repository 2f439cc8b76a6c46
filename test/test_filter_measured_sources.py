"""motion_filter_node starts only from a measured pose it can believe (real DDS, real processes).

The node runs as its own process; this process plays the robot's driver (it publishes the
robot's real pose ``R`` on ``joint_states``) and a second participant on the same topic: a
driver listing a joint twice, a publisher of old or future stamps, a second robot's driver. Its
pose ``W`` is 1.37 rad from ``R`` on one shoulder. Before the fix, the first command came from
``W`` in each case. A driver discovered only after the filter said it was waiting (no state
file) must not find the robot commanded toward neutral. The verdicts are positions (every
command near ``R``, none near ``W``), counts and levels on /diagnostics, and what came in which
order.
"""

from __future__ import annotations

import subprocess
import time

import numpy as np
import pytest
import rclpy
import rclpy.subscription
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from sensor_msgs.msg import JointState

from audio2pose_ros.ros.player import rclpy_session
from audio2pose_ros.ros.supervisor import executable_command
from audio2pose_ros.topics import COMMANDED_JOINT_STATES, DIAGNOSTICS, JOINT_STATES, absolute

pytestmark = [pytest.mark.ros, pytest.mark.slow]
PERIOD = 0.02  # naoqi_driver publishes joint_states at 50 Hz
WARN, ERROR = "1", "2"


class Driver(Node):
    """One publisher of joint_states (a robot's driver, or what else publishes there)."""

    def __init__(self, name: str, names: list[str]) -> None:
        super().__init__(name)
        self.names = names
        self.publisher = self.create_publisher(JointState, absolute(JOINT_STATES), 10)

    def send(self, pose: np.ndarray, ahead_s: float = 0.0, names: list[str] | None = None):
        msg = JointState(name=names or self.names, position=[float(v) for v in pose])
        stamp_ns = self.get_clock().now().nanoseconds + round(ahead_s * 1e9)
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        self.publisher.publish(msg)


class Observer(Node):
    """Records the commands and the filter's diagnostics, in order of arrival."""

    def __init__(self) -> None:
        super().__init__("start_pose_observer")
        self.events: list[tuple[str, object]] = []  # ("command", pose) / ("diagnostics", dict)
        self.create_subscription(
            JointState, absolute(COMMANDED_JOINT_STATES), self.on_command, 1000
        )
        self.create_subscription(DiagnosticArray, DIAGNOSTICS, self.on_diagnostics, 100)

    def on_command(self, msg: JointState) -> None:
        self.events.append(("command", np.array(msg.position)))

    def on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.endswith("motion_filter_node"):
                values = {kv.key: kv.value for kv in status.values}
                values["message"] = status.message
                values["level"] = str(int.from_bytes(status.level, "little"))
                self.events.append(("diagnostics", values))

    def commands(self) -> np.ndarray:
        return np.array([p for kind, p in self.events if kind == "command"])

    def diagnostics(self) -> list[dict[str, str]]:
        return [d for kind, d in self.events if kind == "diagnostics"]  # type: ignore[misc]


@pytest.fixture
def graph(tmp_path, robot):
    """(observer, driver, other, executor) with the filter process started; all torn down."""
    with rclpy_session():
        observer = Observer()
        driver = Driver("robot_driver", list(robot.names))
        other = Driver("second_publisher", list(robot.names))
        executor = rclpy.executors.SingleThreadedExecutor()
        for node in (observer, driver, other):
            executor.add_node(node)
        command = [
            *executable_command("motion_filter_node"),
            "--ros-args",
            "-p",
            "joint_states_rate_hz:=100.0",
            "-p",
            "startup_timeout_s:=5.0",  # discovery is slow on a loaded machine
            "-p",
            f"state_file:={tmp_path / 'filter_state.json'}",
        ]
        with (tmp_path / "motion_filter_node.log").open("w") as log:
            process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)
        end = time.monotonic() + 60
        while time.monotonic() < end and not (
            driver.publisher.get_subscription_count() and other.publisher.get_subscription_count()
        ):
            executor.spin_once(timeout_sec=0.05)
        assert driver.publisher.get_subscription_count(), "motion_filter_node did not come up"
        yield observer, driver, other, executor
        process.terminate()
        process.wait(timeout=10)
        for node in (observer, driver, other):
            node.destroy_node()


def run(executor, seconds: float, *senders) -> None:
    """Spin for ``seconds``, calling each sender once per PERIOD."""
    end, due = time.monotonic() + seconds, time.monotonic()
    while time.monotonic() < end:
        if time.monotonic() >= due:
            for send in senders:
                send()
            due += PERIOD
        executor.spin_once(timeout_sec=0.002)


def latest_after_first_command(observer: Observer, executor, *senders) -> dict[str, str]:
    """The first diagnostics sent after the first command arrived (sending on meanwhile)."""
    end = time.monotonic() + 10
    while time.monotonic() < end:
        kinds = [kind for kind, _ in observer.events]
        if "command" in kinds and "diagnostics" in kinds[kinds.index("command") :]:
            return observer.diagnostics()[-1]
        run(executor, 0.1, *senders)
    raise AssertionError("no diagnostics after the first command")


def real_and_wrong(robot) -> tuple[np.ndarray, np.ndarray]:
    real = robot.neutral_rad.copy()
    joint = robot.names.index("LShoulderPitch")
    real[robot.names.index("LShoulderRoll")] = 0.4  # out: clear of the body
    wrong = real.copy()
    real[joint] = 0.2  # the arm forward
    wrong[joint] = real[joint] + 1.37
    return real, wrong


def assert_started_from(observer: Observer, robot, real: np.ndarray) -> None:
    commands = observer.commands()
    assert len(commands), "nothing was commanded"
    first_step = np.abs(commands[0] - real)
    assert np.all(first_step <= robot.max_velocity_rad_s * 0.01 + 1e-6), first_step.max()
    assert np.abs(commands - real).max() < 0.02  # at rest where the robot is, never elsewhere


def test_when_a_joint_is_listed_twice_expect_no_command_an_error_then_the_real_pose(graph, robot):
    observer, driver, _, executor = graph
    real, wrong = real_and_wrong(robot)
    joint = robot.names.index("LShoulderPitch")
    names = [*robot.names, "LShoulderPitch"]
    twice = np.append(real, wrong[joint])  # the last occurrence says the wrong angle

    run(executor, 2.0, lambda: driver.send(twice, names=names))
    assert not observer.commands().size, "commanded from a message that lists a joint twice"
    held = observer.diagnostics()[-1]
    assert held["started_from"] == "waiting"
    assert int(held["measured_refused_duplicate_names"]) > 0
    assert held["level"] == ERROR  # the start is held: nobody can tell where the robot is
    assert "LShoulderPitch" in held["message"]
    assert "commanding nothing" in held["message"]

    run(executor, 1.5, lambda: driver.send(real))  # the driver is fixed
    started = latest_after_first_command(observer, executor, lambda: driver.send(real))
    assert started["started_from"] == "measured pose"
    assert_started_from(observer, robot, real)


@pytest.mark.parametrize("ahead_s", [-60.0, 3600.0])
def test_when_a_second_publisher_sends_old_or_future_stamps_expect_them_refused(
    graph, robot, ahead_s
):
    """The stale publisher speaks first; the robot's driver starts half a second later."""
    observer, driver, other, executor = graph
    real, wrong = real_and_wrong(robot)
    run(executor, 0.5, lambda: other.send(wrong, ahead_s=ahead_s))
    assert not observer.commands().size
    run(executor, 3.0, lambda: other.send(wrong, ahead_s=ahead_s), lambda: driver.send(real))
    assert_started_from(observer, robot, real)
    latest = observer.diagnostics()[-1]
    counted = "measured_refused_old_stamps" if ahead_s < 0 else "measured_refused_future_stamps"
    assert int(latest[counted]) > 0
    assert latest["level"] >= WARN
    assert "refused" in latest["message"]


def test_when_a_second_robots_driver_publishes_expect_an_error_a_hold_and_recovery(graph, robot):
    """The second robot's driver speaks first, then the robot's own: they disagree by 1.37 rad.
    Nothing is commanded while both speak; when the second stops, the start is from the robot."""
    observer, driver, other, executor = graph
    real, wrong = real_and_wrong(robot)
    run(executor, 0.3, lambda: other.send(wrong))
    run(executor, 3.0, lambda: other.send(wrong), lambda: driver.send(real))
    assert not observer.commands().size, "commanded while two robots' poses disagreed"
    held = [d for d in observer.diagnostics() if "problem: measured_sources" in d]
    assert held, "the two sources were not reported"
    assert held[-1]["level"] == ERROR
    assert "disagree" in held[-1]["message"]
    assert "commanding nothing" in held[-1]["message"]
    assert observer.diagnostics()[-1]["started_from"] == "waiting"

    run(executor, 3.0, lambda: driver.send(real))  # the second robot's driver is stopped
    started = latest_after_first_command(observer, executor, lambda: driver.send(real))
    assert started["started_from"] == "measured pose"
    assert_started_from(observer, robot, real)


def test_when_the_driver_is_discovered_after_the_startup_timeout_expect_no_command_till_its_pose(
    tmp_path, robot
):
    """No state file; the robot's driver appears only after the filter said it was waiting (a
    robot over Wi-Fi, discovered late). Before: the filter started from neutral at
    ``startup_timeout_s`` and commanded the robot there, 1.37 rad from where it stood."""
    real, _ = real_and_wrong(robot)  # the left arm forward, 1.37 rad from neutral
    with rclpy_session():
        observer = Observer()
        executor = rclpy.executors.SingleThreadedExecutor()
        executor.add_node(observer)
        command = [
            *executable_command("motion_filter_node"),
            "--ros-args",
            "-p",
            "joint_states_rate_hz:=100.0",
            "-p",
            f"state_file:={tmp_path / 'filter_state.json'}",  # none yet
        ]
        with (tmp_path / "motion_filter_node.log").open("w") as log:
            process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)
        driver = None
        try:
            end = time.monotonic() + 60
            said = []  # the start's report, once startup_timeout_s has passed
            while time.monotonic() < end and not said:
                executor.spin_once(timeout_sec=0.05)
                said = [
                    d
                    for d in observer.diagnostics()
                    if "problem: start_pose" in d or d["started_from"] != "waiting"
                ]
            assert said, "motion_filter_node did not come up"
            run(executor, 1.0)  # discovery still slower than that
            driver = Driver("late_robot_driver", list(robot.names))
            executor.add_node(driver)
            end = time.monotonic() + 60
            while time.monotonic() < end and not observer.commands().size:
                run(executor, 0.1, lambda: driver.send(real))
            run(executor, 1.0, lambda: driver.send(real))
        finally:
            process.terminate()
            process.wait(timeout=10)
            for node in (observer, driver):
                if node is not None:
                    node.destroy_node()
    assert_started_from(observer, robot, real)  # every command at rest where the robot is
    first = next(i for i, (kind, _) in enumerate(observer.events) if kind == "command")
    before = [d for kind, d in observer.events[:first] if kind == "diagnostics"]
    assert {d["started_from"] for d in before} == {"waiting"}
    assert "no measured pose on joint_states (no publisher)" in said[0]["message"]
    assert "commanding nothing" in said[0]["message"]
    assert observer.diagnostics()[-1]["started_from"] == "measured pose"

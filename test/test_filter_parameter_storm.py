"""motion_filter_node under a storm of set_parameters requests: the commands keep their clock.

The node runs as its own process (the real executable); this process streams a pose on
raw_trajectory, as inference_node does, and keeps 50 set_parameters requests in flight at all
times from each of two processes of its own (parameter_storm.py), as fast as the node answers. The verdict is read from the header stamps of the
commanded joint states (the tick each command was computed at, on the node's clock), so a slow
test process does not make a gap that the node did not make, and from the commanded positions.
"""

from __future__ import annotations

import select
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros.ros.diagnosed_node import trajectory_msg
from audio2pose_ros.ros.graph import executable_command
from audio2pose_ros.topics import COMMANDED_JOINT_STATES, DIAGNOSTICS, RAW_TRAJECTORY, absolute

pytestmark = [pytest.mark.ros, pytest.mark.slow]
PERIOD = 0.01
STORM_S = 3.0
STORM_PROCESSES = 2  # each keeps 50 requests waiting for an answer (parameter_storm.py)
STORM_SCRIPT = Path(__file__).with_name("parameter_storm.py")
MIN_COMMANDS_PER_S = 40  # in every 1 s window (commanded_joint_states runs at 50 Hz here)
MAX_GAP_S = 0.1


class Operator(Node):
    """Streams raw poses, storms the filter's set_parameters, records its commands by stamp."""

    def __init__(self) -> None:
        super().__init__("storm_operator")
        self.raw = self.create_publisher(JointTrajectory, absolute(RAW_TRAJECTORY), 100)
        self.commands: list[tuple[float, np.ndarray]] = []  # (header stamp s, positions)
        self.diagnostics: list[dict[str, str]] = []
        self.create_subscription(
            JointState, absolute(COMMANDED_JOINT_STATES), self.on_command, 1000
        )
        self.create_subscription(DiagnosticArray, DIAGNOSTICS, self.on_diagnostics, 100)

    def on_command(self, msg: JointState) -> None:
        stamp_s = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        self.commands.append((stamp_s, np.array(msg.position)))

    def on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.endswith("motion_filter_node"):
                values = {kv.key: kv.value for kv in status.values}
                values["message"] = status.message
                self.diagnostics.append(values)

    def stream(self, pose: np.ndarray) -> None:
        msg = trajectory_msg(self.robot_names, pose[None, :], PERIOD)
        msg.header.stamp = self.get_clock().now().to_msg()
        self.raw.publish(msg)

    def spin_for(self, seconds: float, pose: np.ndarray) -> None:
        end, next_pose = time.monotonic() + seconds, time.monotonic()
        while time.monotonic() < end:
            if time.monotonic() >= next_pose:
                self.stream(pose)
                next_pose += PERIOD
            rclpy.spin_once(self, timeout_sec=0.002)


def spin_until_each_says(
    operator: Operator, pose: np.ndarray, storms: list[subprocess.Popen]
) -> list[str]:
    """Stream ``pose`` until each storm process has printed its next line; the lines."""
    lines: dict[int, str] = {}
    end = time.monotonic() + 60
    while len(lines) < len(storms) and time.monotonic() < end:
        operator.spin_for(0.02, pose)
        readable, _, _ = select.select([s.stdout for s in storms], [], [], 0)
        for i, storm in enumerate(storms):
            if storm.stdout in readable and i not in lines:
                lines[i] = storm.stdout.readline().strip()
    assert len(lines) == len(storms), "a storm process did not answer"
    return [lines[i] for i in range(len(storms))]


@pytest.fixture
def filter_process(tmp_path):
    command = [
        *executable_command("motion_filter_node"),
        "--ros-args",
        "-p",
        "joint_states_rate_hz:=50.0",
        "-p",
        "startup_timeout_s:=0.3",
        "-p",
        f"state_file:={tmp_path / 'filter_state.json'}",
    ]
    with (tmp_path / "motion_filter_node.log").open("w") as log:
        process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)
    yield process
    process.terminate()
    process.wait(timeout=10)


@pytest.fixture
def operator(robot):
    with rclpy.init():
        node = Operator()
        node.robot_names = list(robot.names)
        yield node
        node.destroy_node()


def raised(robot) -> np.ndarray:
    pose = robot.neutral_rad.copy()
    pose[robot.names.index("LShoulderPitch")] -= 0.8
    pose[robot.names.index("LShoulderRoll")] = 0.4  # forward and out: clear of the body
    pose[robot.names.index("HeadYaw")] += 0.4
    return pose


@pytest.mark.parametrize(
    ("name", "values"),
    [
        ("head_gain", (1.0,)),  # the same value again and again (a slider held still)
        ("velocity_fraction", (0.5, 0.49)),  # alternating: a new limiter each time, before
        ("max_stamp_age_s", (5.0, 6.0)),  # alternating, a node setting
    ],
)
def test_when_set_parameters_storms_expect_commands_every_tick_and_on_their_track(
    operator, filter_process, robot, name, values
):
    pose = raised(robot)
    end = time.monotonic() + 60
    while time.monotonic() < end and not operator.commands:
        operator.spin_for(0.05, pose)
    assert operator.commands, "motion_filter_node did not come up"
    operator.spin_for(2.5, pose)  # settled on the pose
    assert np.abs(operator.commands[-1][1] - pose).max() < 0.01

    storms = [
        subprocess.Popen(
            [sys.executable, str(STORM_SCRIPT), name, str(STORM_S), *map(str, values)],
            stdout=subprocess.PIPE,
            text=True,
        )
        for _ in range(STORM_PROCESSES)
    ]
    lines = spin_until_each_says(operator, pose, storms)  # each found the service
    assert all(line == "storming" for line in lines), lines
    first = len(operator.commands)
    operator.spin_for(STORM_S, pose)
    during = operator.commands[first:]
    results = [line.split() for line in spin_until_each_says(operator, pose, storms)]
    answered = sum(int(answered) for answered, _ in results)
    refused = sum(int(refused) for _, refused in results)

    assert answered >= 100, f"only {answered} requests answered: no storm"
    assert refused == 0
    stamps = np.array([s for s, _ in during])
    positions = np.array([p for _, p in during])
    storm_start, storm_end = stamps[0], stamps[-1]
    assert storm_end - storm_start > STORM_S - 0.5, "commands stopped during the storm"
    gaps = np.diff(stamps)
    worst_gap = gaps.max()
    windows = np.arange(storm_start, storm_end - 1.0, 0.1)
    per_window = [int(((stamps >= w) & (stamps < w + 1.0)).sum()) for w in windows]
    drift = float(np.abs(positions - pose).max())
    print(
        f"{answered / STORM_S:.0f} requests/s answered; {len(stamps)} commands, fewest "
        f"{min(per_window)} in a 1 s window, largest gap {worst_gap * 1e3:.0f} ms, drift "
        f"{drift:.4f} rad"
    )
    assert min(per_window) >= MIN_COMMANDS_PER_S
    assert worst_gap <= MAX_GAP_S
    assert drift < 0.01

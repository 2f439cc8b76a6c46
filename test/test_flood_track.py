"""A flood on one input of the motion filter does not displace its raw poses: commands keep track.

The filter node runs as its own process. This process streams a periodic track of raw poses on
raw_trajectory, one pose per 10 ms as inference_node does, and records the commanded poses by
their header stamps. For two periods the track plays alone; then a separate process floods one
other input of the filter (the robot's /joint_states, or ``stop: false``) as fast as it can
while the track plays on, from the flooder's first message to its last (the flooder's own
stamps). The flood shares the filter's receive path in the middleware and costs a raw pose now
and then; the filter's best-effort reader of raw poses loses that one and takes the next on
time, where a reliable one held every later pose behind the lost one until it was sent again
(0.4-0.9 s): the commands glided to neutral and back, 0.5 rad off. Every command of the flood is
compared with the commands of the quiet periods at the same phase of the track, and stays within
``MAX_DRIFT_RAD`` of them. The verdict is positions against positions; the rates are printed for
the record. Marked long, as the other floods of node processes (a flooder takes a core).
"""

from __future__ import annotations

import queue
import subprocess
import threading
import time
from typing import IO

import flood_publisher
import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros.ros.messages import stamp_s, trajectory_msg
from audio2pose_ros.ros.player import rclpy_session
from audio2pose_ros.ros.qos import STREAM_QOS
from audio2pose_ros.ros.supervisor import executable_command
from audio2pose_ros.topics import (
    COMMANDED_JOINT_STATES,
    DIAGNOSTICS,
    JOINT_STATES,
    RAW_TRAJECTORY,
    absolute,
)

pytestmark = [pytest.mark.ros, pytest.mark.long]
PERIOD_S = 0.01  # one raw pose per 10 ms
TRACK_PERIOD_S = 2.0  # the track repeats: a command is compared at its phase
QUIET_PERIODS = 2
FLOOD_S = 4.0
MAX_DRIFT_RAD = 0.1
JOINTS = ("LShoulderPitch", "RShoulderPitch", "HeadYaw")  # moved by the track, clear of the body


class Operator(Node):
    """The robot's first joint_states (so the filter starts), the track, and the commands."""

    def __init__(self, robot) -> None:
        super().__init__("flood_track_operator")
        self.robot = robot
        self.raw = self.create_publisher(JointTrajectory, absolute(RAW_TRAJECTORY), STREAM_QOS)
        self.states = self.create_publisher(
            JointState, absolute(JOINT_STATES), qos_profile_sensor_data
        )
        self.commands: list[tuple[float, np.ndarray]] = []  # (header stamp s, positions)
        self.create_subscription(
            JointState, absolute(COMMANDED_JOINT_STATES), self.on_command, 1000
        )
        self.filter_values: dict[str, str] = {}  # the filter's last /diagnostics values
        self.create_subscription(DiagnosticArray, DIAGNOSTICS, self.on_diagnostics, 10)
        self.start_s = 0.0
        self.sent_s: list[float] = []  # when each raw pose was sent (wall clock)

    def on_command(self, msg: JointState) -> None:
        self.commands.append((stamp_s(msg.header.stamp), np.array(msg.position)))

    def on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if "motion_filter_node" in status.name:
                self.filter_values = {kv.key: kv.value for kv in status.values}

    def pose(self, at_s: float) -> np.ndarray:
        pose = self.robot.neutral_rad.copy()
        phase = 2 * np.pi * (at_s - self.start_s) / TRACK_PERIOD_S
        for k, name in enumerate(JOINTS):
            pose[self.robot.names.index(name)] += 0.3 * np.sin(phase + k)
        return pose

    def send_pose(self) -> None:
        now = self.get_clock().now()
        msg = trajectory_msg(self.robot.names, self.pose(now.nanoseconds * 1e-9)[None, :], PERIOD_S)
        msg.header.stamp = now.to_msg()
        self.raw.publish(msg)
        self.sent_s.append(time.time())

    def play(self, seconds: float, states: bool = False) -> None:
        end, next_pose = time.monotonic() + seconds, time.monotonic()
        while time.monotonic() < end:
            if time.monotonic() >= next_pose:
                if states:
                    self.states.publish(
                        JointState(
                            name=list(self.robot.names),
                            position=[float(v) for v in self.robot.neutral_rad],
                        )
                    )
                else:
                    self.send_pose()
                next_pose += PERIOD_S
            rclpy.spin_once(self, timeout_sec=0.002)


@pytest.fixture
def filter_process(tmp_path):
    command = [
        *executable_command("motion_filter_node"),
        "--ros-args",
        "-p",
        f"state_file:={tmp_path / 'filter_state.json'}",
        "-p",
        "joint_states_rate_hz:=50.0",
    ]
    with (tmp_path / "motion_filter_node.log").open("w") as log:
        process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)
    yield process
    process.terminate()
    process.wait(timeout=10)


def read_lines(stream: IO[str], lines: queue.Queue[str]) -> None:
    """Put each line of ``stream`` in ``lines`` until it ends (a thread: reading never pauses
    the track, which a read waiting for the flooder would: the filter glides to neutral then)."""
    for line in stream:
        lines.put(line)


def phase_of(operator: Operator, stamp_s: float) -> float:
    return (stamp_s - operator.start_s) % TRACK_PERIOD_S


@pytest.mark.parametrize("kind", ["joint_states", "stop_false"])
def test_when_another_input_floods_expect_commands_within_a_tenth_of_a_radian_of_their_track(
    filter_process, robot, kind
):
    with rclpy_session():
        operator = Operator(robot)
        try:
            deadline = time.monotonic() + 60
            while not operator.commands:  # the robot publishes its pose: the filter starts
                assert time.monotonic() < deadline, "motion_filter_node did not come up"
                operator.play(0.1, states=True)
            operator.start_s = time.time()
            operator.play(TRACK_PERIOD_S)  # settle on the track
            quiet_start = time.time()
            operator.play(QUIET_PERIODS * TRACK_PERIOD_S)
            quiet_end = time.time()
            flooder = flood_publisher.start(kind, FLOOD_S)
            lines: queue.Queue[str] = queue.Queue()  # its stdout, read aside: the track plays on
            reader = threading.Thread(target=read_lines, args=(flooder.stdout, lines))
            reader.start()
            try:
                while flooder.poll() is None:  # the track plays on while the flooder runs
                    operator.play(0.05)
            finally:
                flooder.wait(timeout=60)
                reader.join(timeout=10)
            ready, sent = lines.get_nowait().split(), lines.get_nowait().split()
            assert ready == ["ready"], "the flooder did not find the filter"
            assert sent[0] == "sent", "the flooder did not flood"
            flood_start, flood_end = float(sent[2]), float(sent[3])  # its first and last
            operator.play(0.2)
        finally:
            operator.destroy_node()

    quiet = sorted(
        (phase_of(operator, s), p) for s, p in operator.commands if quiet_start <= s <= quiet_end
    )
    flood_commands = [(s, p) for s, p in operator.commands if flood_start <= s <= flood_end]
    flood = [(phase_of(operator, s), p) for s, p in flood_commands]
    assert quiet, "no commands recorded without the flood"
    assert flood, "no commands recorded during the flood"
    phases = np.array([ph for ph, _ in quiet])
    positions = np.array([p for _, p in quiet])
    moved = [robot.names.index(name) for name in JOINTS]
    drift, worst_s = 0.0, 0.0
    for (phase, position), (stamp, _) in zip(flood, flood_commands, strict=True):
        expected = [np.interp(phase, phases, positions[:, j], period=TRACK_PERIOD_S) for j in moved]
        if (off := float(np.abs(position[moved] - expected).max())) > drift:
            drift, worst_s = off, stamp - flood_start
    stamps = np.array(sorted(s for s, _ in operator.commands if flood_start <= s <= flood_end))
    sent_during = np.array([t for t in operator.sent_s if flood_start <= t <= flood_end])
    values = operator.filter_values
    print(
        f"{kind}: flood of {sent[1]} messages; {len(flood)} commands in "
        f"{flood_end - flood_start:.1f} s (largest gap {np.diff(stamps).max() * 1e3:.0f} ms), "
        f"{len(quiet)} without; {len(sent_during)} raw poses sent (largest gap "
        f"{np.diff(sent_during).max() * 1e3:.0f} ms); largest distance from the quiet track "
        f"{drift:.3f} rad, {worst_s:.2f} s into the flood; the filter's raw messages lost "
        f"{values.get('raw_messages_lost')}, buffer underruns {values.get('buffer_underruns')}, "
        f"poses skipped {values.get('poses_skipped_backlog')}"
    )
    assert drift < MAX_DRIFT_RAD

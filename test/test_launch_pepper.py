"""The real launch file under launch_testing: speech moves the robot, a killed node comes back.

``ros2 launch audio2pose_ros pepper.launch.py`` is started by launch_testing (``colcon test`` on
a ROS 2 distro; launch_testing is a test_depend in package.xml) once per model_path case
(which source wins: launch argument > parameters file > package default. In each run the test plays
speech as audio_capture would (AudioInfo latched, AudioData in 10 ms chunks, real time), checks
that /joint_angles moves and stays inside the robot's limits, kills motion_filter_node and checks
that it is restarted and commands flow again, and after the launch has shut down checks that
every node process ended cleanly.

Where launch_testing is not installed this module is skipped with that reason (the only skip of
the suite); everything it checks is also covered without launch by test/test_launch_support.py,
test/test_package.py and the graph tests that run through ``audio2pose run``.
"""

from __future__ import annotations

import os
import signal
import tempfile
import time
import unittest
from collections.abc import Callable
from pathlib import Path

import pytest

pytest.importorskip(
    "launch_testing",
    reason="launch_testing is not installed (it comes with a ROS 2 distro: "
    "apt install ros-$ROS_DISTRO-launch-testing); the launch file is covered by "
    "test_launch_support.py and test_package.py here",
)

import launch_testing
import launch_testing.actions
import launch_testing.asserts
import numpy as np
import rclpy
from ament_index_python.packages import get_package_share_directory
from audio_common_msgs.msg import AudioInfo
from launch import LaunchDescription
from launch.actions import IncludeLaunchDescription
from launch.launch_description_sources import PythonLaunchDescriptionSource
from naoqi_bridge_msgs.msg import JointAnglesWithSpeed
from rcl_interfaces.srv import GetParameters
from rclpy.node import Node
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros.audio.pcm import S16LE_MONO_16K
from audio2pose_ros.audio.wav import read_wav
from audio2pose_ros.data.bag import (
    AUDIO_DATA_TYPE,
    AUDIO_INFO_TOPIC,
    AUDIO_INFO_TYPE,
    AUDIO_TOPIC,
    audio_messages,
)
from audio2pose_ros.resources import bundled_speech_paths, default_checkpoint_path
from audio2pose_ros.robot.description import load_robot
from audio2pose_ros.ros.player import MessagePlayer, spin_until, warm_up
from audio2pose_ros.timebase import SAMPLE_RATE_HZ
from audio2pose_ros.topics import JOINT_ANGLES, RAW_TRAJECTORY, absolute

SPEECH_S = 3.0
WORK = Path(tempfile.mkdtemp(prefix="test_launch_pepper_"))
IN_FILE = WORK / "from_params_file.safetensors"
IN_ARGUMENT = WORK / "from_argument.safetensors"


def model_path_case(case: str) -> tuple[dict[str, str], str]:
    """Launch arguments of a model_path precedence case, and the model_path the node must get."""
    for copy in (IN_FILE, IN_ARGUMENT):
        if not copy.exists():
            copy.write_bytes(default_checkpoint_path().read_bytes())
    params = WORK / f"{case}.yaml"
    if case == "argument over parameters file":
        # A checkpoint that does not exist: the node would exit 78 if the file won.
        params.write_text('/**:\n  ros__parameters:\n    model_path: "/nonexistent.safetensors"\n')
        return {"params_file": str(params), "model_path": str(IN_ARGUMENT)}, str(IN_ARGUMENT)
    if case == "parameters file over package default":
        params.write_text(f'/**:\n  ros__parameters:\n    model_path: "{IN_FILE}"\n')
        return {"params_file": str(params)}, str(IN_FILE)
    return {}, ""  # package default: config/pepper.yaml says '' (the packaged model)


@pytest.mark.launch_test
@launch_testing.parametrize(
    "case",
    [
        "argument over parameters file",
        "parameters file over package default",
        "package default",
    ],
)
def generate_test_description(case: str) -> tuple[LaunchDescription, dict[str, str]]:
    """The installed launch file with the case's arguments, ready to test at once."""
    arguments, expected_model_path = model_path_case(case)
    launch_file = Path(get_package_share_directory("audio2pose_ros"), "launch", "pepper.launch.py")
    description = LaunchDescription(
        [
            IncludeLaunchDescription(
                PythonLaunchDescriptionSource(str(launch_file)),
                launch_arguments=arguments.items(),
            ),
            launch_testing.actions.ReadyToTest(),
        ]
    )
    return description, {"expected_model_path": expected_model_path}


def node_processes(name: str) -> list[int]:
    """Pids of running child processes of this process (the launch service) named ``name``."""
    pids = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            cmdline = (stat.parent / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        running = fields[0] != "Z"
        if running and int(fields[1]) == os.getpid() and name.encode() in b" ".join(cmdline[:2]):
            pids.append(int(stat.parent.name))
    return pids


class SpeechPlayer(Node):
    """Plays audio_capture's part and records what the graph commands."""

    def __init__(self) -> None:
        """Audio publishers, command and raw-pose subscriptions."""
        super().__init__("test_launch_pepper")
        self.player = MessagePlayer(
            self, [(AUDIO_TOPIC, AUDIO_DATA_TYPE), (AUDIO_INFO_TOPIC, AUDIO_INFO_TYPE)]
        )
        self.angles: list[JointAnglesWithSpeed] = []
        self.raw: list[JointTrajectory] = []
        self.create_subscription(
            JointAnglesWithSpeed, absolute(JOINT_ANGLES), self.angles.append, 1000
        )
        self.create_subscription(JointTrajectory, absolute(RAW_TRAJECTORY), self.raw.append, 1000)

    def spin_for(self, seconds: float) -> None:
        """Process callbacks for ``seconds``."""
        spin_until(self, time.monotonic() + seconds)

    def wait_until(self, condition: Callable[[], bool], timeout_s: float, what: str) -> None:
        """Spin until ``condition()``; fail the test with ``what`` after ``timeout_s``."""
        if not (condition() or spin_until(self, time.monotonic() + timeout_s, condition)):
            raise AssertionError(f"{what} within {timeout_s} s")

    def warm_up(self, timeout_s: float) -> None:
        """Send silence until poses come back: every link of the graph has matched."""
        answered = warm_up(
            self.player, AUDIO_TOPIC, lambda: bool(self.raw) and bool(self.angles), timeout_s
        )
        assert answered, f"no pose came back from the graph within {timeout_s} s"
        self.spin_for(0.3)

    def play_speech(self, seconds: float) -> None:
        """Publish ``seconds`` of a packaged speech recording in real time."""
        wav = bundled_speech_paths()[0]
        samples, _ = read_wav(wav)
        self.player.play(audio_messages(samples[: round(seconds * SAMPLE_RATE_HZ)]))
        self.spin_for(0.5)

    def model_path(self, node: str) -> str:
        """``node``'s model_path parameter, through its get_parameters service."""
        client = self.create_client(GetParameters, f"/{node}/get_parameters")
        assert client.wait_for_service(timeout_sec=30.0), f"{node} has no parameter service"
        future = client.call_async(GetParameters.Request(names=["model_path"]))
        rclpy.spin_until_future_complete(self, future, timeout_sec=10.0)
        return future.result().values[0].string_value


class TestRunningGraph(unittest.TestCase):
    """Checks made while the launch file runs (in name order)."""

    @classmethod
    def setUpClass(cls) -> None:
        """One participant for the whole run."""
        rclpy.init()
        cls.player = SpeechPlayer()
        cls.player.player.publishers[AUDIO_INFO_TOPIC].publish(
            AudioInfo(**S16LE_MONO_16K.audio_info_fields())
        )
        cls.player.warm_up(timeout_s=60.0)

    @classmethod
    def tearDownClass(cls) -> None:
        """Leave the domain."""
        cls.player.destroy_node()
        rclpy.try_shutdown()

    def test_1_when_the_case_sets_model_path_expect_the_ros_precedence(
        self, expected_model_path: str
    ) -> None:
        for node in ("audio_features_node", "inference_node"):
            assert self.player.model_path(node) == expected_model_path, node

    def test_2_when_speech_plays_expect_moving_joint_angles_inside_the_limits(self) -> None:
        robot = load_robot()
        self.player.angles.clear()
        self.player.play_speech(SPEECH_S)
        angles = self.player.angles
        # Commands keep flowing (100 Hz configured; at least half of it on a loaded machine; the
        # rate itself is the motion filter's tests' business).
        assert len(angles) >= 0.5 * 100 * SPEECH_S
        assert all(list(m.joint_names) == list(robot.names) for m in angles)
        positions = np.array([m.joint_angles for m in angles], dtype=np.float64)
        assert np.all(np.isfinite(positions))
        assert np.all(positions >= robot.lower_rad - 1e-5)
        assert np.all(positions <= robot.upper_rad + 1e-5)
        assert np.ptp(positions, axis=0).max() > 0.05  # the voice moves the robot

    def test_3_when_the_motion_filter_is_killed_expect_a_restart_and_commands_again(self) -> None:
        (pid,) = node_processes("motion_filter_node")
        os.kill(pid, signal.SIGKILL)
        self.player.wait_until(
            lambda: [p for p in node_processes("motion_filter_node") if p != pid],
            timeout_s=10.0,
            what="motion_filter_node was not restarted",
        )
        self.player.angles.clear()
        self.player.wait_until(
            lambda: len(self.player.angles) > 50,
            timeout_s=30.0,
            what="no /joint_angles from the restarted motion_filter_node",
        )


@launch_testing.post_shutdown_test()
class TestShutdown(unittest.TestCase):
    """Checks made after the launch has shut down."""

    def test_when_the_launch_ends_expect_every_node_process_ended_cleanly(self, proc_info) -> None:
        # The motion filter killed by test_3 ended with -SIGKILL; everything else, including
        # the restarted filter, ended through Ctrl-C handling with status 0.
        launch_testing.asserts.assertExitCodes(proc_info, allowable_exit_codes=[0, -9])
        assert node_processes("_node") == []

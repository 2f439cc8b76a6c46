"""Shared fixtures: real speech, the robot description, a DDS domain per test run."""

from __future__ import annotations

import atexit
import os
import random
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest

from audio2pose_ros.audio.wav import read_wav
from audio2pose_ros.resources import bundled_speech_path, share_path
from audio2pose_ros.robot.description import RobotDescription, load_robot

# DDS must never leave loopback here, and parallel runs must not see each other's nodes.
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("ROS_DOMAIN_ID", str(random.Random(os.getpid()).randint(1, 100)))
# The motion filter keeps its last pose and a stop in $ROS_HOME across restarts: tests must not
# inherit them from another run, nor leave theirs to the user's ~/.ros.
os.environ["ROS_HOME"] = tempfile.mkdtemp(prefix="audio2pose_test_ros_home_")
atexit.register(shutil.rmtree, os.environ["ROS_HOME"], ignore_errors=True)  # not left in /tmp

SPEECH_DIR = share_path("data", "speech")


@pytest.fixture(scope="session")
def robot() -> RobotDescription:
    return load_robot()


@pytest.fixture(scope="session")
def speech_path() -> Path:
    return bundled_speech_path()


@pytest.fixture(scope="session")
def speech(speech_path: Path) -> np.ndarray:
    """7.1 s of real read speech (LibriVox), 16 kHz mono float32."""
    samples, rate = read_wav(speech_path)
    assert rate == 16000
    return samples


@pytest.fixture(scope="session")
def speech_files() -> list[Path]:
    return sorted(SPEECH_DIR.glob("*.wav"))


@pytest.fixture
def probe():
    """A rclpy participant playing audio_capture and recording the graph (test/graph_probe.py)."""
    import rclpy
    from graph_probe import Probe

    with rclpy.init():
        node = Probe()
        yield node
        node.destroy_node()

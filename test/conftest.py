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
# `make test` runs the suite in pytest-xdist workers gw0, gw1, ..., which inherit the run's
# domain: worker N takes the run's domain + N (Fast DDS allows 0-232), so no two share one.
if os.environ.get("PYTEST_XDIST_WORKER", "").startswith("gw"):
    worker = int(os.environ["PYTEST_XDIST_WORKER"][2:])
    os.environ["ROS_DOMAIN_ID"] = str((int(os.environ["ROS_DOMAIN_ID"]) + worker) % 233)
# The motion filter keeps its last pose and a stop in $ROS_HOME across restarts: tests must not
# inherit them from another run, nor leave theirs to the user's ~/.ros.
os.environ["ROS_HOME"] = tempfile.mkdtemp(prefix="audio2pose_test_ros_home_")
atexit.register(shutil.rmtree, os.environ["ROS_HOME"], ignore_errors=True)  # not left in /tmp

SPEECH_DIR = share_path("data", "speech")


DDS_LANES = 2  # under `make test`: workers that run the DDS tests, each file's in one of them


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Under ``pytest -n N --dist loadgroup`` (``make test``), group the tests for the workers.

    The DDS tests (marked ``ros``) run in :data:`DDS_LANES` lanes: every file's in one lane,
    each lane in one worker, one test after another, on that worker's own domain. They spend
    most of their time waiting for real-time playback, so the other workers meanwhile run the
    tests that start no DDS, one by one; those whose file shares a module- or class-scoped
    fixture stay together (the fixture is made once).
    """
    if config.getoption("dist", "no") != "loadgroup":
        return
    dds: dict[str, int] = {}  # file -> its DDS tests
    for item in items:
        if item.get_closest_marker("ros") is not None:
            dds[item.nodeid.split("::")[0]] = dds.get(item.nodeid.split("::")[0], 0) + 1
    lanes = [0] * DDS_LANES
    lane_of = {}
    for path, count in sorted(dds.items(), key=lambda entry: -entry[1]):  # largest first
        lane_of[path] = lanes.index(min(lanes))
        lanes[lane_of[path]] += count
    for item in items:
        path = item.nodeid.split("::")[0]
        if item.get_closest_marker("ros") is not None:
            item.add_marker(pytest.mark.xdist_group(f"dds{lane_of[path]}"))
        elif any(
            definitions[-1].scope in ("module", "class")
            for definitions in item._fixtureinfo.name2fixturedefs.values()
        ):
            item.add_marker(pytest.mark.xdist_group(path))


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

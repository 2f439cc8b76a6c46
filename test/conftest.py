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
from audio2pose_ros.ros.player import rclpy_session

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


DDS_LANES = 1  # under `make test`: the workers that run the DDS tests, one test at a time each


def _shares_a_fixture(item: pytest.Item) -> bool:
    """Whether the test uses a module- or class-scoped fixture (made once for its file)."""
    return any(
        definitions[-1].scope in ("module", "class")
        for definitions in item._fixtureinfo.name2fixturedefs.values()
    )


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Under ``pytest -n N --dist loadgroup`` (``make test``), group the tests for the workers.

    The DDS tests (marked ``ros``) run in :data:`DDS_LANES` lanes, each lane in one worker, one
    test after another, on that worker's own domain: in collection order, each test joins the
    lane with the fewest so far (a file whose tests share a fixture joins as a whole). They
    spend most of their time waiting for real-time playback, so the other workers meanwhile run
    the tests that start no DDS, one by one; those that share a module- or class-scoped fixture
    run together, in one worker (the fixture is made once).
    """
    if config.getoption("dist", "no") != "loadgroup":
        return
    lanes = [0] * DDS_LANES  # tests in each lane so far
    lane_of: dict[str, int] = {}  # files whose DDS tests share a fixture -> their lane
    for item in items:
        path = item.nodeid.split("::")[0]
        if item.get_closest_marker("ros") is not None:
            if not _shares_a_fixture(item):
                lane = lanes.index(min(lanes))
            elif path not in lane_of:
                lane = lane_of[path] = lanes.index(min(lanes))
            else:
                lane = lane_of[path]
            lanes[lane] += 1
            item.add_marker(pytest.mark.xdist_group(f"dds{lane}"))
        elif _shares_a_fixture(item):
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
    from graph_probe import Probe

    with rclpy_session():
        node = Probe()
        yield node
        node.destroy_node()

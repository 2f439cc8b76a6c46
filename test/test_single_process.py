"""Single-process mode: the three nodes in one process give the same poses.

The same 3 s of real speech is played into the graph run as three processes and as one; the
model (a frame-wise MLP) and the feature extractor are deterministic and do not depend on how
the audio is chunked or when it arrives, so the raw trajectories must be identical, point for
point. The commands that follow them depend on the filter's clock (when each tick falls), so
for those the test checks what timing cannot change: both modes command the robot through all
its joints, within its limits, at the configured 50 Hz.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from naoqi_bridge_msgs.msg import JointAnglesWithSpeed
from rclpy.serialization import deserialize_message
from stateless_model import stateless_checkpoint
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros.data.bag import Chunking, audio_messages, read_messages
from audio2pose_ros.robot.description import RobotDescription, load_robot
from audio2pose_ros.ros.messages import stamp_s
from audio2pose_ros.ros.player import rclpy_session
from audio2pose_ros.ros.recorder import play_and_record
from audio2pose_ros.ros.supervisor import SINGLE_PROCESS, node_graph
from audio2pose_ros.topics import JOINT_ANGLES, RAW_TRAJECTORY, absolute

SPEECH_S = 3.0
STALL_S = 0.05  # a spacing of 2.5 command periods: the filter process stalled


def _run(
    tmp_path: Path, speech: np.ndarray, single_process: bool, monkeypatch: pytest.MonkeyPatch
) -> dict[str, list]:
    """Play the speech into the graph; the recorded raw poses and /joint_angles commands."""
    mode = "single" if single_process else "three"
    monkeypatch.setenv("ROS_HOME", str(tmp_path / f"{mode}_ros_home"))  # no saved pose or stop
    messages = audio_messages(speech[: int(SPEECH_S * 16000)], Chunking(seed=3))
    bag = tmp_path / f"{mode}_bag"
    model = stateless_checkpoint(tmp_path / "mlp.safetensors", load_robot(), speech)
    with (
        node_graph(
            log_dir=tmp_path / f"{mode}_logs",
            single_process=single_process,
            overrides=[f"model_path:={model}"],
            no_robot=True,
        ) as graph,
        rclpy_session(),
    ):
        processes = dict(graph.processes)
        play_and_record(messages, bag, tail_s=0.5)
    raw = [
        np.asarray(p.positions)
        for m in read_messages(bag, [absolute(RAW_TRAJECTORY)])
        for p in deserialize_message(m.data, JointTrajectory).points
    ]
    commands = [
        deserialize_message(m.data, JointAnglesWithSpeed)
        for m in read_messages(bag, [absolute(JOINT_ANGLES)])
    ]
    return {"processes": list(processes), "raw": raw, "commands": commands}


@pytest.mark.ros
@pytest.mark.slow
def test_when_the_nodes_share_one_process_expect_the_same_raw_poses_and_commands(
    tmp_path: Path, speech: np.ndarray, robot: RobotDescription, monkeypatch: pytest.MonkeyPatch
) -> None:
    three = _run(tmp_path, speech, False, monkeypatch)
    single = _run(tmp_path, speech, True, monkeypatch)
    assert single["processes"] == [SINGLE_PROCESS]
    assert len(three["processes"]) == 3
    frames = int(SPEECH_S * 100)
    assert frames - 5 <= len(single["raw"]) <= frames + 5
    n = min(len(three["raw"]), len(single["raw"]))
    assert n >= frames - 5
    np.testing.assert_array_equal(np.array(single["raw"][:n]), np.array(three["raw"][:n]))
    for run in (three, single):
        poses = np.array([command.joint_angles for command in run["commands"]])
        stamps_s = np.array([stamp_s(command.header.stamp) for command in run["commands"]])
        assert (poses >= robot.lower_rad - 1e-6).all()
        assert (poses <= robot.upper_rad + 1e-6).all()
        assert np.ptp(poses, axis=0).max() > 0.05  # the speech moved the robot
        # at the commands' pace (50 Hz), judged on the filter's own stamps (the recorder's
        # arrival times add its own scheduling: a median spacing of 25.5 ms on a loaded
        # machine, the arrivals alternating early and late) and between stalls: a stall of the
        # process on a loaded machine leaves one long gap, and moved the mean rate to 34.7 Hz
        spacing_s = np.diff(stamps_s)
        steady = spacing_s[spacing_s < STALL_S]
        assert len(steady) >= 0.9 * len(spacing_s), np.round(spacing_s * 1e3, 1)
        rate_hz = 1.0 / float(np.mean(steady))
        assert 45.0 <= rate_hz <= 55.0, (rate_hz, np.round(spacing_s * 1e3, 1))

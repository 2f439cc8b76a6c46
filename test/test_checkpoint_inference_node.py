"""inference_node with hostile checkpoints and hostile feature frames.

A crafted checkpoint ends the real node process at start-up with one line and exit status 78
(never respawned); absurd feature values are made safe before the model, counted, and every
frame still yields one pose inside the joint limits.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from node_processes import configuration_error_line
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros.ros.messages import features_to_msg
from audio2pose_ros.ros.player import rclpy_session


@pytest.fixture
def node(monkeypatch):
    """An InferenceNode on the packaged model whose published trajectories are collected."""

    from audio2pose_ros.ros.nodes.inference_node import InferenceNode

    with rclpy_session():
        inference = InferenceNode()
        published: list[JointTrajectory] = []  # what it sends
        monkeypatch.setattr(inference.trajectory_pub, "publish", published.append)
        # raw_trajectory is built only for a subscriber: play one
        monkeypatch.setattr(inference.trajectory_pub, "get_subscription_count", lambda: 1)
        inference.published = published
        yield inference
        inference.destroy_node()


def features(node, frames: np.ndarray):  # a Float32MultiArray
    spec = node.model.features
    return features_to_msg(frames.astype(np.float32), f"{spec.kind}{spec.dim}")


@pytest.mark.ros
def test_when_features_are_non_finite_or_absurd_expect_one_safe_pose_per_frame(node, robot):
    mean, std = node.model.normalizer.mean, node.model.normalizer.std
    frames = np.tile(mean, (4, 1))
    frames[1, 3] = np.inf
    frames[2, 5] = np.nan
    frames[3, :] = 1e30
    node.on_features(features(node, frames))
    (msg,) = node.published
    poses = np.array([p.positions for p in msg.points])
    assert poses.shape == (4, robot.n_joints)  # no frame dropped: timing kept
    assert np.isfinite(poses).all()
    assert (poses >= robot.lower_rad).all()
    assert (poses <= robot.upper_rad).all()
    assert node.values_replaced == 2
    assert node.values_clamped == frames.shape[1]
    # The 1e30 frame is treated exactly as a frame at the clamp limit.
    node.published.clear()
    node.predictor = node.model.predictor()
    limit = np.tile(mean, (4, 1))  # non-finite values become the mean
    limit[3, :] = mean + node.settings.feature_limit_sd * std
    node.on_features(features(node, limit))
    np.testing.assert_allclose(
        np.array([p.positions for p in node.published[0].points]), poses, atol=1e-5
    )


@pytest.mark.ros
def test_when_a_message_holds_a_minute_of_frames_expect_only_the_cap_used(node):
    from audio2pose_ros.ros.nodes.inference_node import MAX_FRAMES_PER_MESSAGE

    frames = np.tile(node.model.normalizer.mean, (6000, 1))
    node.on_features(features(node, frames))
    assert len(node.published[0].points) == MAX_FRAMES_PER_MESSAGE
    assert node.frames_dropped == 6000 - MAX_FRAMES_PER_MESSAGE


@pytest.mark.ros
def test_when_the_features_publisher_restarts_expect_a_counted_restart_not_lost_frames(node):
    frames = np.tile(node.model.normalizer.mean, (5, 1)).astype(np.float32)
    label = f"{node.model.features.kind}{node.model.features.dim}"
    for first in (0, 5, 20, 0, 5):  # 10 frames lost before frame 20; a new stream at 0
        node.on_features(features_to_msg(frames, label, first))
    values = node.diagnostic_values()
    assert values["frames_lost"] == 10
    assert values["feature_stream_restarts"] == 1
    assert len(node.published) == 5  # every message served


@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.parametrize(
    ("content", "problem"),
    [
        (b"[" * 10_000 + b"]" * 10_000, "nests 10000 levels deep"),
        (b'{"__metadata__": [1]}', "not an audio2pose checkpoint"),
    ],
)
def test_when_the_checkpoint_is_crafted_expect_one_line_and_exit_78(
    tmp_path: Path, content: bytes, problem: str
):
    model = tmp_path / "crafted.safetensors"
    model.write_bytes(struct.pack("<Q", len(content)) + content)
    line = configuration_error_line("inference_node", "-p", f"model_path:={model}")
    assert "crafted.safetensors" in line
    assert problem in line


@pytest.mark.ros
def test_when_a_features_label_is_huge_expect_its_warning_and_heartbeat_short(node, monkeypatch):
    """A label quoted in a warning would otherwise ride on every heartbeat for seconds."""
    heartbeats = []
    monkeypatch.setattr(node.diagnostics_pub, "publish", heartbeats.append)
    node.on_features(
        features_to_msg(np.zeros((1, node.model.features.dim), np.float32), "x" * 300_000)
    )
    node.publish_diagnostics()
    (status,) = heartbeats[-1].status
    assert node.frames_dropped == 1
    assert len(status.message) < 2000
    assert all(len(kv.key) + len(kv.value) < 2000 for kv in status.values)


@pytest.mark.ros
def test_when_a_layout_claims_frames_without_data_expect_a_malformed_message_not_a_count(node):
    """A 100-byte message whose layout says 4294967295 frames of 0 features carries no frame."""
    from std_msgs.msg import Float32MultiArray, MultiArrayDimension

    msg = Float32MultiArray()
    msg.layout.dim = [
        MultiArrayDimension(label="frames from 0", size=2**32 - 1, stride=0),
        MultiArrayDimension(label=node.expected_label, size=0, stride=0),
    ]
    node.on_features(msg)
    assert node.frames_dropped == 0
    assert node.diagnostic_values()["malformed_messages_dropped"] == 1


@pytest.mark.ros
def test_when_a_frame_index_jumps_beyond_what_time_allows_expect_a_new_stream_not_a_loss(node):
    """'frames from 10**15' right after frame 0: not 10**15 frames lost."""
    frames = np.zeros((2, node.model.features.dim), np.float32)
    node.on_features(features_to_msg(frames, node.expected_label, 0))
    node.on_features(features_to_msg(frames, node.expected_label, 10**15))
    assert node.diagnostic_values()["frames_lost"] == 0
    assert node.sequence.restarts == 1
    node.on_features(features_to_msg(frames, node.expected_label, 10**15 + 12))
    assert node.diagnostic_values()["frames_lost"] == 10  # a plausible gap still counts


@pytest.mark.parametrize("bad", [np.nan, -np.inf, 8.5, -1e30])
def test_when_features_are_within_the_limit_expect_them_unchanged_and_one_bad_value_caught(bad):
    """Speech stays within the limit: nothing to replace or clamp, and the values as they came
    (the quick path); one bad value anywhere takes the full path and is counted."""
    from audio2pose_ros.ros.nodes.inference_node import sanitize_features

    frames = np.random.default_rng(0).uniform(-8.0, 8.0, (20, 26))
    frames[3, 4] = -8.0
    safe, replaced, clamped = sanitize_features(frames, 8.0)
    assert (replaced, clamped) == (0, 0)
    assert np.array_equal(safe, frames)
    frames[19, 25] = bad
    safe, replaced, clamped = sanitize_features(frames, 8.0)
    assert (replaced, clamped) == ((1, 0) if not np.isfinite(bad) else (0, 1))
    assert np.array_equal(safe[:19], frames[:19])
    assert safe[19, 25] == (0.0 if not np.isfinite(bad) else np.sign(bad) * 8.0)
    assert sanitize_features(np.empty((0, 26)), 8.0)[0].shape == (0, 26)

"""inference_node's model switched live over real DDS: the node as its own process, this process
feeding it real speech features a message at a time and setting its model_path through its
parameter service.

A bad checkpoint is refused with the reason while the poses go on from the same model; a good one
(the packaged model with the arms' noise of an enrolment) is blended in: the poses published are,
message by message, the old model's mixed with the new one's from the first message after the
switch, with no step beyond either model's own plus the blend's bound, and the node reports the
new checkpoint once the blend is done. Judged by message order and positions only: each message
is sent after the answer to the one before has arrived.
"""

from __future__ import annotations

import subprocess
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from personal_models import arms_noise_checkpoint
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rclpy.node import Node
from std_msgs.msg import Float32MultiArray
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros.audio.features import extract_features
from audio2pose_ros.checkpoints.numpy_runtime import load_streaming_model
from audio2pose_ros.models.blend import BLEND_FRAMES, PoseBlend, blend_step_bound
from audio2pose_ros.ros.messages import features_to_msg
from audio2pose_ros.ros.nodes.inference_node import SLICE_FRAMES
from audio2pose_ros.ros.player import rclpy_session
from audio2pose_ros.ros.qos import STREAM_QOS
from audio2pose_ros.ros.supervisor import executable_command
from audio2pose_ros.topics import DIAGNOSTICS, FEATURES, RAW_TRAJECTORY, absolute

pytestmark = [pytest.mark.ros, pytest.mark.slow]
FRAMES = 10  # per features message
BEFORE, REFUSED, AFTER = 8, 4, 16  # messages before the bad path, before the good one, after


class Feeder(Node):
    """Sends features, collects raw poses in order, sets the node's model_path."""

    def __init__(self, label: str) -> None:
        super().__init__("model_switch_feeder")
        self.label = label
        self.features = self.create_publisher(Float32MultiArray, absolute(FEATURES), STREAM_QOS)
        self.poses: list[np.ndarray] = []  # one (FRAMES, joints) array per message, in order
        self.create_subscription(JointTrajectory, absolute(RAW_TRAJECTORY), self.on_raw, 100)
        self.reports: list[dict[str, str]] = []
        self.create_subscription(DiagnosticArray, DIAGNOSTICS, self.on_diagnostics, 100)
        self.set_client = self.create_client(SetParameters, "/inference_node/set_parameters")
        self.sent = 0

    def on_raw(self, msg: JointTrajectory) -> None:
        self.poses.append(np.array([p.positions for p in msg.points]))

    def on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.endswith("inference_node"):
                self.reports.append({kv.key: kv.value for kv in status.values})

    def spin_until(self, done: Callable[[], bool], what: str, timeout_s: float = 60.0) -> None:
        end = time.monotonic() + timeout_s  # a bound on a hang only, not a verdict
        while not done():
            assert time.monotonic() < end, f"never: {what}"
            rclpy.spin_once(self, timeout_sec=0.05)

    def send(self, frames: np.ndarray) -> None:
        """One message, then wait for its poses (lock-step: nothing waits, nothing is late)."""
        expected = len(self.poses) + 1
        self.features.publish(features_to_msg(frames, self.label, self.sent))
        self.sent += len(frames)
        self.spin_until(lambda: len(self.poses) == expected, f"poses of message {expected}")

    def set_model_path(self, path: str) -> Any:
        request = SetParameters.Request()
        value = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=path)
        request.parameters = [Parameter(name="model_path", value=value)]
        future = self.set_client.call_async(request)
        self.spin_until(future.done, "the answer to set_parameters")
        return future.result().results[0]


def _offline(model, frames: np.ndarray, messages: int) -> np.ndarray:
    """A model's poses of ``frames``, run as the node runs them (slices of each message)."""
    predictor = model.predictor(seed=0)
    out = []
    for m in range(messages):
        chunk = model.normalizer.apply(frames[m * FRAMES : (m + 1) * FRAMES])
        for s in range(0, FRAMES, SLICE_FRAMES):
            out.append(model.robot.denormalize(predictor.run(chunk[s : s + SLICE_FRAMES])))
    return np.concatenate(out)


def test_when_model_path_is_set_live_expect_bad_ones_refused_and_a_good_one_blended_in(
    tmp_path, robot, speech
):
    from audio2pose_ros.resources import default_checkpoint_path

    personal = arms_noise_checkpoint(tmp_path / "model.safetensors", robot)
    junk = tmp_path / "junk.safetensors"
    junk.write_bytes(b"\x00" * 64)
    old_model = load_streaming_model(default_checkpoint_path(), robot=robot)
    new_model = load_streaming_model(personal, robot=robot)
    spec = old_model.features
    total = BEFORE + REFUSED + AFTER
    frames = extract_features(speech, spec)[: total * FRAMES].astype(np.float32)
    assert len(frames) == total * FRAMES

    log = (tmp_path / "inference_node.log").open("w")
    process = subprocess.Popen([*executable_command("inference_node")], stdout=log, stderr=log)
    try:
        with rclpy_session():
            feeder = Feeder(f"{spec.kind}{spec.dim}")
            try:
                feeder.spin_until(
                    lambda: (
                        feeder.features.get_subscription_count() > 0
                        and feeder.set_client.service_is_ready()
                    ),
                    "inference_node's features subscription and parameter service",
                )
                feeder.spin_until(
                    lambda: feeder.count_publishers(absolute(RAW_TRAJECTORY)) > 0,
                    "inference_node's raw_trajectory publisher",
                )
                end = time.monotonic() + 1.0  # its publisher matches this subscription too
                feeder.spin_until(lambda: time.monotonic() > end, "the match")
                for m in range(BEFORE):
                    feeder.send(frames[m * FRAMES : (m + 1) * FRAMES])
                reasons = []
                for bad in (tmp_path / "missing.safetensors", junk, tmp_path):
                    result = feeder.set_model_path(str(bad))
                    assert not result.successful
                    reasons.append(result.reason)
                assert "no such file" in reasons[0]
                assert "not an audio2pose checkpoint" in reasons[1]
                assert "a folder without style.yaml" in reasons[2]
                for m in range(BEFORE, BEFORE + REFUSED):  # the poses go on, same model
                    feeder.send(frames[m * FRAMES : (m + 1) * FRAMES])
                result = feeder.set_model_path(str(personal))
                assert result.successful, result.reason
                switch = (BEFORE + REFUSED) * FRAMES
                for m in range(BEFORE + REFUSED, total):
                    feeder.send(frames[m * FRAMES : (m + 1) * FRAMES])
                feeder.spin_until(
                    lambda: (
                        bool(feeder.reports)
                        and feeder.reports[-1].get("model_file") == str(personal)
                    ),
                    "the node reporting the new checkpoint",
                )
                assert feeder.reports[-1]["model_blend"] == "none"
                assert int(feeder.reports[-1]["model_switches"]) == 1
            finally:
                feeder.destroy_node()
    finally:
        process.terminate()
        process.wait(20)
        log.close()

    published = np.concatenate(feeder.poses)
    assert len(published) == total * FRAMES  # every frame gave a pose, refusals or not
    old = _offline(old_model, frames, total)
    new_frames = frames[switch:]
    new = _offline(new_model, new_frames, AFTER)
    expected = old.copy()
    expected[switch:] = PoseBlend().mix(old[switch:], new)
    # up to the switch, the old model alone (the refused paths changed nothing); from it on, the
    # blend; BLEND_FRAMES later, the new model alone
    np.testing.assert_allclose(published, expected, atol=1e-5)
    np.testing.assert_allclose(published[switch + BLEND_FRAMES :], new[BLEND_FRAMES:], atol=1e-5)
    step = np.abs(np.diff(published[switch - 1 :], axis=0))
    own_old = np.abs(np.diff(old[switch - 1 :], axis=0))
    own_new = np.abs(np.diff(np.vstack([old[switch - 1], new]), axis=0))
    gap = np.abs(np.vstack([old[switch - 1], new]) - old[switch - 1 :])[:-1]
    assert (step <= blend_step_bound(own_old, own_new, gap) + 1e-5).all()
    # a switch without the blend would have jumped by the models' difference
    assert np.abs(new - old[switch:]).max() > step.max() + 1e-3

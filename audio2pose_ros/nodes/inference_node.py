"""inference_node: feature frames in, raw joint trajectories of the 11 joints out (100 Hz points).

Subscriptions:
    features (std_msgs/Float32MultiArray): frames x features from audio_features_node.
Publications:
    raw_trajectory (trajectory_msgs/JointTrajectory): one point per feature frame, 10 ms apart,
        positions in radians, unsmoothed (motion_filter_node smooths and limits them).
    /diagnostics (diagnostic_msgs/DiagnosticArray)

Parameters
----------
    model_path (str): checkpoint to run ('' = packaged default). Must be a streaming model.
    robot_description (str): robot YAML ('' = packaged Pepper); the checkpoint must match it.

A checkpoint that is missing, modified, offline-only or made for other joints stops the node at
start-up with an error that says why (a launch file then reports the failure; nothing restarts in a
loop). Feature messages of the wrong shape or with non-finite values are dropped with a warning.

"""

from __future__ import annotations

import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from std_msgs.msg import Float32MultiArray
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros.models import OfflineOnlyModelError, require_streaming
from audio2pose_ros.models.checkpoint import load_checkpoint
from audio2pose_ros.nodes.common import (
    DIAGNOSTICS_PERIOD_S,
    STREAM_QOS,
    StartupError,
    diagnostic_array,
    msg_to_features,
    run_node,
    trajectory_msg,
)
from audio2pose_ros.resources import default_checkpoint_path
from audio2pose_ros.robot import load_robot

WARN_THROTTLE_S = 5.0


class InferenceNode(Node):
    """Run a streaming pose model frame by frame."""

    def __init__(self) -> None:
        """Load and check the model, then wire topics."""
        super().__init__("inference_node")
        model_path = self.declare_parameter("model_path", "").value or default_checkpoint_path()
        try:
            robot = load_robot(self.declare_parameter("robot_description", "").value)
            self.checkpoint = load_checkpoint(model_path, robot=robot)
        except (OSError, ValueError) as exc:
            raise StartupError(str(exc)) from None
        model = self.checkpoint.model
        try:
            require_streaming(model, str(model_path))
        except OfflineOnlyModelError as exc:
            raise StartupError(str(exc)) from None
        self.predictor = model.streaming_predictor()
        self.robot = robot
        spec = self.checkpoint.features
        self.expected_label = f"{spec.kind}{spec.dim}"
        self.period_s = spec.step_s
        self.frames_in = 0
        self.frames_dropped = 0
        self.compute_s = 0.0
        self.last_problem = ""

        self.trajectory_pub = self.create_publisher(JointTrajectory, "raw_trajectory", STREAM_QOS)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_subscription(Float32MultiArray, "features", self.on_features, STREAM_QOS)
        self.create_timer(DIAGNOSTICS_PERIOD_S, self.publish_diagnostics)
        self.get_logger().info(
            f"streaming model {model.name} from {model_path}, "
            f"expects {self.expected_label} features"
        )

    def on_features(self, msg: Float32MultiArray) -> None:
        """Normalise, predict each frame, publish one trajectory point per frame.

        Each kind of bad input has its own warning (rclpy throttles per call site).
        """
        log = self.get_logger()
        try:
            frames, label = msg_to_features(msg)
        except ValueError as exc:
            self.last_problem = f"malformed features message dropped: {exc}"
            log.warning(self.last_problem, throttle_duration_sec=WARN_THROTTLE_S)
            return
        if label != self.expected_label or frames.shape[1] != self.checkpoint.features.dim:
            self.frames_dropped += len(frames)
            self.last_problem = (
                f"features {label!r} x{frames.shape[1]} dropped: the model "
                f"expects {self.expected_label!r}"
            )
            log.warning(self.last_problem, throttle_duration_sec=WARN_THROTTLE_S)
            return
        finite = np.isfinite(frames).all(axis=1)
        if not finite.all():
            self.frames_dropped += int(np.count_nonzero(~finite))
            self.last_problem = "feature frames with NaN/inf dropped"
            log.warning(self.last_problem, throttle_duration_sec=WARN_THROTTLE_S)
            frames = frames[finite]
        if not len(frames):
            return
        start = time.perf_counter()
        normalized = self.checkpoint.normalizer.apply(frames)
        poses = np.array([self.predictor.step(frame) for frame in normalized])
        angles = self.robot.denormalize(poses)
        self.compute_s += time.perf_counter() - start
        self.frames_in += len(frames)
        out = trajectory_msg(self.robot.names, angles, self.period_s)
        out.header.stamp = self.get_clock().now().to_msg()
        self.trajectory_pub.publish(out)

    def publish_diagnostics(self) -> None:
        """Publish frame counters and the mean compute time per frame."""
        mean_us = 1e6 * self.compute_s / self.frames_in if self.frames_in else 0.0
        level = DiagnosticStatus.WARN if self.frames_dropped else DiagnosticStatus.OK
        self.diagnostics_pub.publish(
            diagnostic_array(
                self,
                level,
                self.last_problem or "ok",
                {
                    "model": self.checkpoint.model.name,
                    "frames_in": self.frames_in,
                    "frames_dropped": self.frames_dropped,
                    "mean_compute_us_per_frame": f"{mean_us:.1f}",
                },
            )
        )


def main(args: list[str] | None = None) -> None:
    """Run the node until shutdown."""
    run_node(InferenceNode, "inference_node", args)


if __name__ == "__main__":
    main()

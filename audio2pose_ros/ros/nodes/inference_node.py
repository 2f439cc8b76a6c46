"""inference_node: feature frames in, raw joint trajectories of the 11 joints out (100 Hz points).

Subscriptions:
    features (std_msgs/Float32MultiArray): frames x features from audio_features_node (in
        single-process mode that node calls this one directly instead).
Publications:
    raw_trajectory (trajectory_msgs/JointTrajectory): one point per feature frame, 10 ms apart,
        positions in radians, unsmoothed (motion_filter_node smooths and limits them); one
        message per features message, while something subscribes to it.
    /diagnostics (diagnostic_msgs/DiagnosticArray): heartbeat every 0.5 s (DiagnosedNode).

Parameters: the fields of :class:`InferenceNodeSettings` (robot_description and seed read-only;
model_path and feature_limit_sd live); ``ros2 param describe`` shows each one's range.

``model_path`` set while the node runs switches the model without a restart. The parameter
service's callback (never the features callback) loads and checks the checkpoint
(:func:`~audio2pose_ros.checkpoints.switch.load_replacement`: the start-up checks, the running
model's features, a numpy kernel); a checkpoint that fails them is refused with the reason and
the running model goes on. An accepted one runs beside the old one from the next features
message, their poses mixed over :data:`~audio2pose_ros.models.blend.BLEND_FRAMES` frames
(:class:`~audio2pose_ros.models.blend.PoseBlend`), after which the old one stops: the output
never jumps, and it is raw poses as before, limited and guarded by motion_filter_node. While a
blend has begun, another switch is refused (try again when it is done); ``/diagnostics`` names
the checkpoint running (``model_file``) and the blend under way (``model_blend``).

Models with a numpy kernel (``mlp``, ``lstm``, ``live``, ``live_groups``: every streaming model
this package trains) run without torch (:mod:`audio2pose_ros.checkpoints.numpy_runtime`; the
MLP computes a message's frames with one product per layer); a streaming model without a kernel
would be loaded with torch.

A checkpoint or robot file that is missing, modified, crafted, offline-only or made for other
joints is a ConfigurationError at start-up: ``run_node`` prints one line and exits with status
78, which supervisors never respawn.

Bad input never reaches the model and never stops the node:

- a message of the wrong layout or feature set is dropped and reported;
- frames lost on the way are counted (``frames_lost``) and reported as WARN: audio_features_node
  numbers its messages' first frames (``"frames from N"`` in the layout), and a message that
  starts past the next expected frame shows that the messages between were dropped, as a
  reliable subscription's queue does when the node falls behind; a message that starts before
  it is a new stream (its publisher restarted), counted as ``feature_stream_restarts`` and
  logged, not a loss;
- at most :data:`MAX_FRAMES_PER_MESSAGE` frames of one message are used (10 s of audio; the
  rest is dropped and counted), computed :data:`SLICE_FRAMES` at a time with the node's
  heartbeat free to run between slices, so one message cannot silence the node;
- a message that waited more than :data:`MAX_FEATURES_WAIT_S` for the node (fed faster than it
  computes, or on a machine slower than real time) is behind real time: its frames are dropped
  unserved and counted (``frames_behind_real_time``, WARN ``behind real time``), so the node
  catches up instead of computing stale poses, and keeps its heartbeat: a supervisor never
  restarts it for being busy;
- after normalisation, non-finite values are replaced by 0 (the training mean) and values
  beyond +-``feature_limit_sd`` are clamped; both are counted and reported as WARN. The frame
  is kept, so the output stays one pose per 10 ms frame.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from std_msgs.msg import Float32MultiArray
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros import topics
from audio2pose_ros.checkpoints.numpy_runtime import (
    FramePredictor,
    StreamingModel,
    load_streaming_model,
)
from audio2pose_ros.checkpoints.switch import load_replacement, resolve_model_path
from audio2pose_ros.errors import ConfigurationError, InputError
from audio2pose_ros.models.blend import PoseBlend
from audio2pose_ros.parameters import (
    ParameterValue,
    param,
    settings_from,
    settings_with,
    specs_of,
    validate_settings,
)
from audio2pose_ros.robot.description import load_robot
from audio2pose_ros.ros.diagnosed_node import DiagnosedNode
from audio2pose_ros.ros.messages import msg_to_features, trajectory_msg
from audio2pose_ros.ros.node_parameters import NodeParameters
from audio2pose_ros.ros.qos import STREAM_QOS
from audio2pose_ros.ros.spin import run_node
from audio2pose_ros.ros.subscriptions import MessageInfo
from audio2pose_ros.timebase import FrameSequence

# 10 s of 10 ms frames (about 20 ms of work for the packaged model); audio_features_node sends
# one message per audio chunk, typically 1 to 20 frames.
MAX_FRAMES_PER_MESSAGE = 1000
# A features message of MAX_FRAMES_PER_MESSAGE frames of up to 256 float32 features and its layout;
# anything larger is dropped before rclpy decodes it (its layout list could be any length).
MAX_FEATURES_BYTES = 4096 + MAX_FRAMES_PER_MESSAGE * 256 * 4
# A message's frames are computed this many at a time, the node's paced timers (its heartbeat)
# running between slices: one message of MAX_FRAMES_PER_MESSAGE frames never silences the node.
SLICE_FRAMES = 5
# A features message that waited longer than this between its reception and the node serving
# it is behind real time: its frames are dropped unserved and counted (frames_behind_real_time).
MAX_FEATURES_WAIT_S = 0.5


@dataclass(frozen=True)
class InferenceNodeSettings:
    """The inference node's parameters (one definition: descriptors, YAML, docs, settings)."""

    model_path: str = field(
        default="",
        metadata=param(
            "checkpoint to run ('' = packaged default); must be a streaming model; set live, "
            "the new model is blended in over 1 s (a checkpoint for other joints or features, "
            "or without a numpy kernel, is refused and the running one goes on)",
        ),
    )
    robot_description: str = field(
        default="",
        metadata=param(
            "robot description YAML ('' = packaged Pepper); the checkpoint must match it",
            read_only=True,
        ),
    )
    feature_limit_sd: float = field(
        default=8.0,
        metadata=param(
            "normalised features are clamped to +- this many training standard deviations",
            minimum=1.0,
            maximum=1000.0,
            unit="sd",
        ),
    )
    seed: int = field(
        default=0,
        metadata=param(
            "seed of a sampling model's noise: the same seed gives the same motion for the "
            "same audio",
            minimum=0,
            maximum=2**31 - 1,
            read_only=True,
        ),
    )

    def __post_init__(self) -> None:
        """Validate every field against its declaration."""
        validate_settings(self)


PARAMETERS = specs_of(InferenceNodeSettings)


def sanitize_features(normalized: np.ndarray, limit_sd: float) -> tuple[np.ndarray, int, int]:
    """Make normalised features safe for the model.

    Args:
        normalized: (n_frames, n_features) z-normalised features.
        limit_sd: values are clamped to [-limit_sd, limit_sd].

    Returns:
        ``(features, n_non_finite, n_clamped)``: a copy with non-finite values replaced by 0
        (the training mean) and the others clamped, and how many values each rule changed;
        ``normalized`` itself when every value is finite and within the limit (speech nearly
        always: two numpy calls instead of seven).
    """
    if np.abs(normalized).max(initial=0.0) <= limit_sd:  # False for a NaN
        return normalized, 0, 0
    finite = np.isfinite(normalized)
    n_non_finite = int(normalized.size - np.count_nonzero(finite))
    safe = np.where(finite, normalized, 0.0)
    n_clamped = int(np.count_nonzero(np.abs(safe) > limit_sd))
    return np.clip(safe, -limit_sd, limit_sd), n_non_finite, n_clamped


PoseSink = Callable[[np.ndarray, float], None]  # (angles in self.robot's joint order, stamp s)


class InferenceNode(DiagnosedNode):
    """Run a streaming pose model frame by frame."""

    def __init__(self, subscribe: bool = True) -> None:
        """Declare parameters, load and check the model, then wire topics.

        Args:
            subscribe: take features from the ``features`` topic; False in single-process mode,
                where audio_features_node calls :meth:`on_frames` directly.

        Raises:
            ConfigurationError: a refused parameter, or an unusable checkpoint or robot file.
        """
        super().__init__("inference_node")
        self.parameters = NodeParameters(self, PARAMETERS, apply=self.apply_parameters)
        self.settings = settings_from(InferenceNodeSettings, self.parameters.values)
        model_path = resolve_model_path(self.settings.model_path)
        self.robot = load_robot(self.settings.robot_description or None)
        self.joint_names = self.robot.names
        self.model = load_streaming_model(model_path, robot=self.robot)
        self.predictor = self.model.predictor(seed=self.settings.seed)
        self.model_file = str(model_path)  # the checkpoint running
        # a model set live, run beside the old one until the blend ends: (model, its
        # predictor, its file), and the blend
        self.incoming: tuple[StreamingModel, FramePredictor, str] | None = None
        self.blend: PoseBlend | None = None
        self.model_switches = 0  # blends finished
        spec = self.model.features
        self.expected_label = spec.label
        self.period_s = spec.step_s
        self.frames_in = 0
        self.frames_dropped = 0
        self.frames_behind = 0  # frames of messages that waited over MAX_FEATURES_WAIT_S
        self.malformed_messages = 0  # features messages whose layout does not fit their data
        self.sequence = FrameSequence()  # frames lost between features messages
        self.values_replaced = 0
        self.values_clamped = 0
        self.compute_s = 0.0

        # In single-process mode motion_filter_node is called directly (nodes.single_process);
        # raw_trajectory is then published only for other subscribers.
        self.pose_sink: PoseSink | None = None
        self.trajectory_pub = self.create_publisher(
            JointTrajectory, topics.RAW_TRAJECTORY, STREAM_QOS
        )
        if subscribe:
            self.create_bounded_subscription(
                Float32MultiArray, topics.FEATURES, self.on_features, STREAM_QOS,
                MAX_FEATURES_BYTES, with_info=True,
            )  # fmt: skip
        self.get_logger().info(
            f"streaming model {self.model.name} ({self.model.runtime} runtime) from "
            f"{model_path}, expects {self.expected_label} features"
        )

    def apply_parameters(self, changes: Mapping[str, ParameterValue]) -> None:
        """Adopt a validated run-time change: feature_limit_sd, or model_path (a switch).

        Raises:
            ConfigurationError: the checkpoint of a new model_path is refused
                (:func:`~audio2pose_ros.checkpoints.switch.load_replacement`), or a blend to
                another model has begun; nothing changes then.
        """
        if "model_path" in changes:
            if self.blend is not None and self.blend.done:
                raise ConfigurationError(
                    f"model_path not changed: the switch to {self.incoming_file()} is under way "
                    f"({self.blend.done}/{self.blend.frames} frames blended); set it again "
                    "when it is done"
                )
            path = str(changes["model_path"])
            model = load_replacement(path, self.model, self.robot)
            # a switch not begun yet (no frames since) is replaced: nothing of it was published
            self.incoming = (
                model,
                model.predictor(seed=self.settings.seed),
                str(resolve_model_path(path)),
            )
            self.blend = PoseBlend()
            self.get_logger().info(
                f"switching to {self.incoming[2]} ({model.name}): blended in over "
                f"{self.blend.frames} frames from the next features"
            )
        self.settings = settings_with(self.settings, changes)

    def incoming_file(self) -> str:
        """The checkpoint being blended in ('' when none)."""
        return self.incoming[2] if self.incoming is not None else ""

    def on_features(self, msg: Float32MultiArray, info: MessageInfo | None = None) -> None:
        """Unpack a features message and run it (:meth:`on_frames`), unless it is too late.

        A message that waited more than :data:`MAX_FEATURES_WAIT_S` since the middleware
        received it (``info``) came while the node was busy with the ones before: the node is
        behind real time (fed faster than it computes, or on a machine too slow), and poses of
        it would be stale. Its frames are dropped unserved, counted in
        ``frames_behind_real_time`` and reported as WARN; dropping costs next to nothing, so
        the node catches up with the stream instead of falling further behind.
        """
        try:
            batch = msg_to_features(msg)
        except InputError as exc:  # a layout that does not fit the data
            self.malformed_messages += 1
            self.report_problem(
                "malformed", DiagnosticStatus.WARN, f"malformed features message dropped: {exc}"
            )
            return
        restarts = self.sequence.restarts
        missing = self.sequence.observe(batch.first_frame, len(batch.frames), time.monotonic())
        if self.sequence.restarts > restarts:
            self.get_logger().info(
                f"the features stream started again at frame {batch.first_frame} (its publisher "
                f"restarted); {self.sequence.restarts} restarts in all",
                throttle_duration_sec=5.0,
            )
        if missing:
            self.report_problem(
                "frames lost",
                DiagnosticStatus.WARN,
                f"{missing} feature frames lost before frame {batch.first_frame} (messages "
                "dropped on the way: the node fell behind and its subscription queue kept only "
                f"the newest, or the network lost them); {self.sequence.lost} lost in all",
            )
        waited_s = _waited_s(info)
        if waited_s > MAX_FEATURES_WAIT_S:
            self.frames_behind += len(batch.frames)
            self.report_problem(
                "behind real time",
                DiagnosticStatus.WARN,
                f"features dropped unserved: a message waited {waited_s:.2f} s for the node "
                f"(more than {MAX_FEATURES_WAIT_S:g} s: fed faster than it computes); "
                f"{self.frames_behind} frames in all",
            )
            return
        self.on_frames(batch.frames, batch.label)

    def on_frames(self, frames: np.ndarray, label: str) -> None:
        """Normalise, make safe, predict each frame, send one trajectory point per frame.

        The trajectory is published on raw_trajectory while something subscribes to it, and
        handed to :attr:`pose_sink` when one is set (single-process mode).
        """
        if label != self.expected_label or frames.shape[1] != self.model.features.dim:
            self.frames_dropped += len(frames)
            self.report_problem(
                "wrong features",
                DiagnosticStatus.WARN,
                f"features {label!r} x{frames.shape[1]} dropped: the model expects "
                f"{self.expected_label!r}",
            )
            return
        if len(frames) > MAX_FRAMES_PER_MESSAGE:
            self.frames_dropped += len(frames) - MAX_FRAMES_PER_MESSAGE
            self.report_problem(
                "too many frames",
                DiagnosticStatus.WARN,
                f"a message of {len(frames)} frames: frames beyond {MAX_FRAMES_PER_MESSAGE} "
                "dropped",
            )
            frames = frames[:MAX_FRAMES_PER_MESSAGE]
        if not len(frames):
            return
        start = time.perf_counter()
        with np.errstate(invalid="ignore", over="ignore"):  # inf - inf: made safe just below
            normalized = self.model.normalizer.apply(frames)
        safe, replaced, clamped = sanitize_features(normalized, self.settings.feature_limit_sd)
        if replaced or clamped:
            self.values_replaced += replaced
            self.values_clamped += clamped
            self.report_problem(
                "feature values",
                DiagnosticStatus.WARN,
                f"feature values made safe: {replaced} non-finite replaced by the mean, "
                f"{clamped} clamped to +-{self.settings.feature_limit_sd:g} sd",
            )
        incoming = None
        if self.incoming is not None:  # its own normalisation: checkpoints may differ in it
            with np.errstate(invalid="ignore", over="ignore"):
                normalized_new = self.incoming[0].normalizer.apply(frames)
            incoming = sanitize_features(normalized_new, self.settings.feature_limit_sd)[0]
        poses = []
        for begin in range(0, len(safe), SLICE_FRAMES):  # the node's timers run between slices
            end = begin + SLICE_FRAMES
            pose = self.robot.denormalize(self.predictor.run(safe[begin:end]))
            if incoming is not None:
                pose = self._blended(pose, incoming[begin:end])
                if self.incoming is None:  # the blend ended: the new model runs alone
                    safe, incoming = incoming, None
            poses.append(pose)
            self.run_overdue_timers(time.monotonic())
        angles = np.concatenate(poses)
        self.compute_s += time.perf_counter() - start
        self.frames_in += len(frames)
        stamp = self.get_clock().now()
        if self.trajectory_pub.get_subscription_count():  # no message for nobody
            msg = trajectory_msg(self.joint_names, angles, self.period_s)
            msg.header.stamp = stamp.to_msg()
            self.trajectory_pub.publish(msg)
        if self.pose_sink is not None:
            self.pose_sink(angles, stamp.nanoseconds * 1e-9)

    def _blended(self, old: np.ndarray, features: np.ndarray) -> np.ndarray:
        """The old model's poses mixed with the incoming one's; ends the blend when it is done."""
        assert self.incoming is not None
        assert self.blend is not None
        model, predictor, file = self.incoming
        new = self.robot.denormalize(predictor.run(features))
        mixed = self.blend.mix(old, new)
        if self.blend.finished:
            self.model, self.predictor, self.model_file = model, predictor, file
            self.incoming, self.blend = None, None
            self.model_switches += 1
            self.get_logger().info(f"now running {file} ({model.name}) alone")
        return mixed

    def diagnostic_values(self) -> dict[str, object]:
        """Frame and value counters, the model running and the mean compute time per frame."""
        mean_us = 1e6 * self.compute_s / self.frames_in if self.frames_in else 0.0
        blend = (
            f"{self.blend.done}/{self.blend.frames} frames toward {self.incoming_file()}"
            if self.blend is not None
            else "none"
        )
        return {
            "model": self.model.name,
            "model_file": self.model_file,
            "model_blend": blend,
            "model_switches": self.model_switches,
            "runtime": self.model.runtime,
            "frames_in": self.frames_in,
            "frames_dropped": self.frames_dropped,
            "frames_behind_real_time": self.frames_behind,
            "malformed_messages_dropped": self.malformed_messages,
            "frames_lost": self.sequence.lost,
            "feature_stream_restarts": self.sequence.restarts,
            "feature_values_replaced": self.values_replaced,
            "feature_values_clamped": self.values_clamped,
            "feature_limit_sd": self.settings.feature_limit_sd,
            "mean_compute_us_per_frame": f"{mean_us:.1f}",
        }


def _waited_s(info: MessageInfo | None) -> float:
    """How long a message waited since the middleware received it (0 when unknown)."""
    if info is None:
        return 0.0
    received_ns = info.get("received_timestamp") or info.get("source_timestamp") or 0
    return time.time() - received_ns * 1e-9 if received_ns else 0.0


def main(args: list[str] | None = None) -> None:
    """Run the node until shutdown; a configuration error exits with status 78."""
    run_node(InferenceNode, "inference_node", args)


if __name__ == "__main__":
    main()

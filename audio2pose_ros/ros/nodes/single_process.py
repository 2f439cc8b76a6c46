"""The three nodes in one process and one executor: the smallest footprint.

``audio2pose run --single-process`` and ``ros2 launch audio2pose_ros pepper.launch.py
single_process:=true`` start this instead of the three node executables. The nodes are the same
classes with the same names, parameters and outputs, but they pass the stream to each other by
direct calls (:func:`connect`), since rclpy has no intra-process transport: audio_features_node
hands each chunk's feature frames and voice activity changes to the next nodes, and
inference_node its poses (numpy arrays, never a message) to motion_filter_node, which checks them
as it checks a raw_trajectory message (start, stamp, points per message, gate). ``features``,
``voice_activity`` and ``raw_trajectory`` are still published for any other subscriber (a
recorder, a viewer), but are not inputs of this process. One interpreter, one copy of numpy and
rclpy, and one executor serve all three. A configuration error in any node ends the process with
status 78 like a single node's; every node keeps its own /diagnostics heartbeat (all with this
process's pid).

Run it as ``python -m audio2pose_ros.ros.nodes.single_process [--ros-args ...]``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, cast

if TYPE_CHECKING:
    from rclpy.node import Node

    from audio2pose_ros.ros.nodes.audio_features_node import AudioFeaturesNode
    from audio2pose_ros.ros.nodes.inference_node import InferenceNode
    from audio2pose_ros.ros.nodes.motion_filter_node import MotionFilterNode

PROCESS_NAME = "audio2pose_nodes"
NODE_NAMES = ("audio_features_node", "inference_node", "motion_filter_node")


def connect(nodes: list[Node]) -> None:
    """Wire the built nodes (features, inference, filter) to each other by direct calls.

    Raises:
        ConfigurationError: the filter's robot has a joint the model's robot lacks.
    """
    import numpy as np

    from audio2pose_ros.errors import ConfigurationError

    features = cast("AudioFeaturesNode", nodes[0])
    inference = cast("InferenceNode", nodes[1])
    motion = cast("MotionFilterNode", nodes[2])
    model_names = list(inference.robot.names)
    missing = [name for name in motion.robot.names if name not in model_names]
    if missing:
        raise ConfigurationError(
            f"robot_description: the model's robot has no joints {missing} that "
            "motion_filter_node commands"
        )
    order = np.array([model_names.index(name) for name in motion.robot.names])
    # Each call passes the receiving node's boundary: its exceptions are its own to report.
    run_frames = inference.guarded(inference.on_frames)
    queue_poses = motion.guarded(motion.on_poses)
    features.features_sink = lambda frames: run_frames(frames, features.label)
    features.voice_sink = motion.guarded(motion.on_voice_active)
    inference.pose_sink = lambda angles, stamp_s: queue_poses(angles[:, order], stamp_s)


def main(args: list[str] | None = None) -> None:
    """Build the three nodes in one context, connect them, spin them in one executor."""
    from functools import partial

    from audio2pose_ros.ros.nodes.audio_features_node import AudioFeaturesNode
    from audio2pose_ros.ros.nodes.inference_node import InferenceNode
    from audio2pose_ros.ros.nodes.motion_filter_node import MotionFilterNode
    from audio2pose_ros.ros.spin import run_nodes

    run_nodes(
        [
            AudioFeaturesNode,
            partial(InferenceNode, subscribe=False),
            partial(MotionFilterNode, subscribe_graph=False),
        ],
        PROCESS_NAME,
        args,
        connect=connect,
    )


if __name__ == "__main__":
    from audio2pose_ros.ros.nodes.process import lighten_node_imports, prepare_node_process

    prepare_node_process()  # before the imports in main(): die with the parent, quit on SIGTERM
    lighten_node_imports()
    main()

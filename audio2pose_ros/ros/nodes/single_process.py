"""The three nodes in one process and one executor (issue 15): the smallest footprint.

``audio2pose run --single-process`` and ``ros2 launch audio2pose_ros pepper.launch.py
single_process:=true`` start this instead of the three node executables. The nodes are the same
classes with the same names, parameters, topics and outputs; they still talk over the
middleware (rclpy has no intra-process transport), but one interpreter, one copy of numpy and
rclpy, and one executor serve all three. A configuration error in any node ends the process
with status 78 like a single node's; every node keeps its own /diagnostics heartbeat (all with
this process's pid).

Run it as ``python -m audio2pose_ros.ros.nodes.single_process [--ros-args ...]``.
"""

from __future__ import annotations

PROCESS_NAME = "audio2pose_nodes"
NODE_NAMES = ("audio_features_node", "inference_node", "motion_filter_node")


def main(args: list[str] | None = None) -> None:
    """Build the three nodes in one context and spin them in one executor until shutdown."""
    from audio2pose_ros.ros.diagnosed_node import run_nodes
    from audio2pose_ros.ros.nodes.audio_features_node import AudioFeaturesNode
    from audio2pose_ros.ros.nodes.inference_node import InferenceNode
    from audio2pose_ros.ros.nodes.motion_filter_node import MotionFilterNode

    run_nodes([AudioFeaturesNode, InferenceNode, MotionFilterNode], PROCESS_NAME, args)


if __name__ == "__main__":
    from audio2pose_ros.ros.nodes.process import prepare_node_process

    prepare_node_process()  # before the imports in main(): die with the parent, quit on SIGTERM
    main()

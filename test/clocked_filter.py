"""motion_filter_node in this process on a controlled clock and a controlled graph.

Each message and each start-up check goes through the callback the executor would call, in a
fixed order, so a test sets what the graph shows and when each message arrives.
"""

from __future__ import annotations

import time
from types import SimpleNamespace

import numpy as np
import rclpy
from sensor_msgs.msg import JointState

from audio2pose_ros.motion.state_file import FilterMemory, save_memory


def clocked_nodes(tmp_path, monkeypatch, robot):
    """Build motion_filter_node on a controlled monotonic clock and a controlled graph.

    A fixture's body (``yield from``): it yields ``make``. ``make(saved=..., without=...)``
    returns (node, clock, graph, saved pose): set ``clock.now`` and ``graph.publishers`` (the
    gid bytes of the publishers the graph shows) before each call. ``saved``: a state file with
    a pose the robot reported before; ``without``: start_without_measured_pose.
    """
    from audio2pose_ros.ros.nodes import motion_filter_node as module

    clock = SimpleNamespace(now=0.0)
    graph = SimpleNamespace(publishers=[])
    monkeypatch.setattr(
        module, "time", SimpleNamespace(monotonic=lambda: clock.now, time=time.time)
    )
    monkeypatch.setattr(
        module.MotionFilterNode,
        "publisher_ids",
        lambda self, topic: [bytes([gid] * 16) for gid in graph.publishers],
        raising=False,  # (the start asked the graph for a count before it told gids apart)
    )
    built = []

    def make(saved: bool = True, without: bool = False):
        state = tmp_path / "state.json"
        saved_pose = robot.neutral_rad.copy()
        if saved:
            save_memory(
                state,
                FilterMemory(
                    tuple(robot.names),
                    tuple(float(v) for v in saved_pose),
                    False,
                    time.time(),
                    measured=True,
                ),
            )
        args = ["--ros-args", "-p", f"state_file:={state}"]
        args += ["-p", f"start_without_measured_pose:={str(without).lower()}"]
        rclpy.init(args=args)  # returns nothing before Kilted: remember it was called
        built.append("rclpy")
        node = module.MotionFilterNode(subscribe_graph=False)
        built.append(node)
        return node, clock, graph, saved_pose

    yield make
    for thing in reversed(built):
        if isinstance(thing, module.MotionFilterNode):
            thing.destroy_node()
        elif thing is not None:
            rclpy.try_shutdown()


def measured(robot, pose, gid: int = 1):
    """A measured message of publisher ``gid`` (its gid padded to 24 bytes, as rclpy gives it)."""
    message = JointState(name=list(robot.names), position=[float(v) for v in pose])
    info = {"publisher_gid": {"data": bytes([gid] * 16 + [0] * 8)}, "source_timestamp": 0}
    return message, info


def moved_arm(robot) -> np.ndarray:
    """Where the robot is: its left arm moved 0.6 rad while the filter was down."""
    pose = robot.neutral_rad.copy()
    pose[robot.names.index("LShoulderPitch")] -= 0.6
    return pose

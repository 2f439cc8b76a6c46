"""The simulated Pepper: setAngles speeds, replaced targets, trajectories, refused commands."""

from __future__ import annotations

import numpy as np
import pytest

from audio2pose_ros.errors import InputError
from audio2pose_ros.robot.simulated_pepper import SimulatedPepper
from audio2pose_ros.ros.player import rclpy_session


@pytest.fixture
def sim():
    robot = SimulatedPepper()
    yield robot
    robot.close()


def test_when_set_angles_at_a_tenth_of_max_speed_expect_that_speed(sim):
    robot = sim.robot
    joint = robot.names.index("LShoulderPitch")
    start = sim.measured()[0][joint]
    sim.set_angles(["LShoulderPitch"], [start - 1.0], 0.1)
    sim.step(0.5)
    moved = start - sim.measured()[0][joint]
    assert moved == pytest.approx(0.5 * 0.1 * robot.max_velocity_rad_s[joint], rel=0.05)


def test_when_set_angles_at_full_speed_expect_target_reached_and_held(sim):
    sim.set_angles(["HeadYaw", "LShoulderPitch"], [0.8, 0.6], 1.0)
    sim.step(0.5)
    positions, velocities = sim.measured()
    names = sim.robot.names
    assert positions[names.index("HeadYaw")] == pytest.approx(0.8, abs=1e-3)
    assert positions[names.index("LShoulderPitch")] == pytest.approx(0.6, abs=1e-3)
    assert np.abs(velocities).max() < 1e-2


def test_when_a_new_command_arrives_expect_it_replaces_the_old_target(sim):
    sim.set_angles(["HeadYaw"], [1.5], 0.2)
    sim.step(0.1)
    sim.set_angles(["HeadYaw"], [-0.2], 1.0)
    sim.step(0.5)
    assert sim.measured()[0][sim.robot.names.index("HeadYaw")] == pytest.approx(-0.2, abs=1e-3)


def test_when_target_out_of_range_expect_clamped_to_the_joint_limit(sim):
    sim.set_angles(["HipRoll"], [3.0], 1.0)
    sim.step(1.0)
    joint = sim.robot.names.index("HipRoll")
    assert sim.measured()[0][joint] == pytest.approx(sim.robot.upper_rad[joint], abs=1e-3)


def test_when_a_trajectory_is_sent_expect_its_points_reached_on_time(sim):
    sim.follow(["HeadPitch"], [0.2, 0.4], np.array([[0.1], [0.3]]))
    joint = sim.robot.names.index("HeadPitch")
    start = sim.measured()[0][joint]
    sim.step(0.1)
    assert sim.measured()[0][joint] == pytest.approx(start + (0.1 - start) / 2, abs=0.02)
    sim.step(0.15)
    assert sim.measured()[0][joint] == pytest.approx(0.15, abs=0.02)  # between the points
    sim.step(0.5)
    assert sim.measured()[0][joint] == pytest.approx(0.3, abs=1e-3)


@pytest.mark.parametrize(
    ("names", "angles", "speed", "problem"),
    [
        (["Knee"], [0.0], 0.5, "unknown joints"),
        (["HeadYaw"], [float("nan")], 0.5, "finite"),
        (["HeadYaw", "HeadPitch"], [0.0], 0.5, "2 joint names but 1 angles"),
        (["HeadYaw"], [0.3], 0.0, "speed"),
        (["HeadYaw"], [0.3], float("inf"), "speed"),
        (["HeadYaw"], [0.3], 1.5, "speed"),
    ],
)
def test_when_command_malformed_expect_refused_and_robot_unchanged(
    sim, names, angles, speed, problem
):
    before = sim.measured()[0]
    with pytest.raises(InputError, match=problem):
        sim.set_angles(names, angles, speed)
    sim.step(0.2)
    np.testing.assert_allclose(sim.measured()[0], before, atol=1e-6)
    assert sim.counts.refused == 1


def test_when_arm_commanded_into_the_body_expect_the_self_collision_counted(sim):
    sim.set_angles(
        ["LShoulderPitch", "LShoulderRoll", "LElbowRoll", "LElbowYaw"],
        [1.3, 0.13, -1.24, 0.28],
        1.0,
    )
    sim.step(1.0)
    assert sim.counts.self_collision_steps > 0
    assert sim.counts.deepest_m > 0.05


def test_when_a_commanded_trajectory_is_executed_expect_it_tracked_and_measured():
    """render --executed: the robot's measured pose follows a slow sweep closely, lags a sweep
    faster than the commanded speed allows, and an unknown joint set is refused."""
    from audio2pose_ros.offline.trajectory import Trajectory, TrajectoryError, executed_trajectory
    from audio2pose_ros.robot.description import load_robot

    robot = load_robot()
    times = np.arange(200) * 0.01
    pitch = robot.names.index("LShoulderPitch")

    def sweep(rad_s: float) -> Trajectory:
        angles = np.tile(robot.neutral_rad, (len(times), 1))
        angles[:, pitch] -= np.minimum(rad_s * times, 3.0)  # within LShoulderPitch's range
        return Trajectory("sweep", times, angles, tuple(robot.names))

    slow = executed_trajectory(sweep(0.5), robot, 0.5)  # well under 0.5 x 7.3 rad/s
    assert np.degrees(slow.error_rad).max() < 2.0
    assert slow.self_collision_steps == 0
    assert slow.trajectory.angles_rad.shape == (len(times), robot.n_joints)
    fast = executed_trajectory(sweep(6.0), robot, 0.5)  # faster than 0.5 x 7.3 rad/s
    assert fast.error_rad.max() > 0.5  # capped at 3.7 rad/s, it falls behind, as Pepper would
    assert fast.error_rad[-1] < 0.02  # and catches up once the target holds still
    wrong = Trajectory("wrong", times, np.zeros((len(times), 1)), ("Elbow",))
    with pytest.raises(TrajectoryError, match="no angles for joints"):
        executed_trajectory(wrong, robot, 0.5)


def test_when_the_arms_swing_between_their_limits_expect_every_measured_pose_within_them(sim):
    """pybullet's motors overshoot a target at a limit: the simulated joint stops there."""
    robot, names = sim.robot, list(sim.robot.names)
    worst = np.zeros(robot.n_joints)
    for target in (robot.upper_rad, robot.lower_rad, robot.upper_rad):
        sim.set_angles(names, list(target), 1.0)
        for _ in range(200):
            sim.step(0.005)
            position, _ = sim.measured()
            beyond = np.maximum(position - robot.upper_rad, robot.lower_rad - position)
            worst = np.maximum(worst, beyond)
    assert worst.max() <= 1e-9, dict(zip(names, worst.round(4), strict=True))


@pytest.mark.ros
def test_when_a_command_names_a_huge_joint_expect_a_short_refusal_on_the_heartbeat(monkeypatch):
    """The refusal quotes the name; the node's status must not carry 60 kB twice a second."""
    from naoqi_bridge_msgs.msg import JointAnglesWithSpeed

    from audio2pose_ros.ros.nodes.pepper_sim_node import PepperSimNode

    with rclpy_session():
        node = PepperSimNode()
        try:
            sent = []
            monkeypatch.setattr(node.diagnostics_pub, "publish", sent.append)
            msg = JointAnglesWithSpeed(joint_names=["y" * 60_000], joint_angles=[0.0], speed=0.5)
            node.on_joint_angles(msg)
            node.publish_diagnostics()
            (status,) = sent[-1].status
            assert node.sim.counts.refused == 1
            assert len(status.message) < 2000
        finally:
            node.destroy_node()

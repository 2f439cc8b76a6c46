"""robot/capsules.py: capsules that contain Pepper's collision shapes, against the exact model."""

from __future__ import annotations

import pickle
import subprocess
import sys
import textwrap
from dataclasses import replace

import numpy as np
import pytest
from body_poses import INSIDE, pose_with

from audio2pose_ros.robot.body import BodyModel
from audio2pose_ros.robot.capsules import (
    CapsuleModel,
    CapsuleModelError,
    bounding_capsules,
    segment_distances,
)
from audio2pose_ros.robot.kinematics import RobotKinematics
from audio2pose_ros.robot.pairs import ARM_LINK_PREFIXES

# measured on 3,000 poses drawn within the joint limits (seed 0): the capsule clearance is at
# most 2.59 cm below the exact one (median 0.36 cm), and within 5 cm of the body at most
# 2.25 cm below it (median 0.16 cm)
MAX_UNDER_M = 0.03
NEAR_MAX_UNDER_M = 0.025
NEAR_MEDIAN_UNDER_M = 0.003


@pytest.fixture(scope="module")
def capsules(robot):
    return CapsuleModel.load(robot)


@pytest.fixture(scope="module")
def exact(robot):
    return BodyModel.load(robot)


@pytest.fixture(scope="module")
def random_poses(robot):
    rng = np.random.default_rng(0)
    return rng.uniform(robot.lower_rad, robot.upper_rad, size=(3000, robot.n_joints))


def test_when_random_poses_expect_the_capsule_clearance_never_above_the_exact_one(
    capsules, exact, random_poses
):
    """Conservative: capsules contain the shapes. Close: a few cm at most, as stated."""
    ours, truth = capsules.clearance(random_poses), exact.clearance(random_poses)
    # coal answers within 1e-6 m; overlapping shapes give overlapping capsules
    assert np.all(ours <= np.maximum(truth, 0.0) + 1e-6)
    apart = truth >= 0.0
    under = (truth - ours)[apart]
    near = (truth - ours)[apart & (truth < 0.05)]
    print(
        f"capsule clearance below the exact one: max {100 * under.max():.2f} cm, "
        f"median {100 * np.median(under):.2f} cm; within 5 cm of the body ({near.size} poses): "
        f"max {100 * near.max():.2f} cm, median {100 * np.median(near):.2f} cm"
    )
    assert apart.sum() > 2500
    assert near.size > 1000
    assert under.max() < MAX_UNDER_M
    assert near.max() < NEAR_MAX_UNDER_M
    assert np.median(near) < NEAR_MEDIAN_UNDER_M
    assert np.all(ours[~apart] < 0.0)  # a pose in the body is in the capsules too


def test_when_checked_pairs_are_listed_expect_the_exact_models_links(capsules, exact):
    """One pair rule for both models (robot/pairs.py)."""
    assert set(capsules.link_pairs) == set(exact.link_pairs)


def test_when_a_pose_is_in_the_body_expect_the_same_pair_closest(capsules, exact, robot):
    pose = pose_with(robot, **INSIDE)
    distances = capsules.pair_distances(pose)[0]
    arm_link, other = capsules.link_pairs[int(np.argmin(distances))]
    assert arm_link in ARM_LINK_PREFIXES["left"]
    assert other == "torso"
    assert distances.min() <= exact.clearance(pose) < -0.05


def test_when_joints_turn_expect_no_pair_nearer_than_its_lever_allows(capsules, random_poses):
    """pair_lever_m bounds how much each pair's distance can change (body-aware sampling)."""
    rng = np.random.default_rng(1)
    start = random_poses[:400]
    moved = start + rng.normal(0.0, 0.05, size=start.shape)
    change = np.abs(capsules.pair_distances(moved) - capsules.pair_distances(start))
    bound = np.abs(moved - start) @ capsules.pair_lever_m.T
    assert np.all(change <= bound + 1e-9)
    assert (change / np.maximum(bound, 1e-12)).max() > 0.3  # a bound, not a blanket


def test_when_shapes_are_bounded_expect_every_point_inside_a_capsule():
    rng = np.random.default_rng(2)
    for shape in RobotKinematics().collisions:
        capsules = bounding_capsules(shape)
        unit = rng.uniform(-1.0, 1.0, size=(4000, 3))
        if shape.kind == "box":
            local = 0.5 * unit * np.asarray(shape.size)
        else:  # cylinder or sphere: points of the shape's bounding box that lie in it
            radius = shape.size[0]
            half = 0.5 * shape.size[1] if shape.kind == "cylinder" else radius
            local = unit * [radius, radius, half]
            keep = (
                np.hypot(local[:, 0], local[:, 1]) <= radius
                if shape.kind == "cylinder"
                else np.linalg.norm(local, axis=1) <= radius
            )
            local = local[keep]
        points = local @ shape.origin[:3, :3].T + shape.origin[:3, 3]
        inside = np.zeros(len(points), dtype=bool)
        for a, b, radius in capsules:
            ends = [np.broadcast_to(end, points.shape) for end in (a, b)]
            gaps = segment_distances(points, points, *ends)
            inside |= gaps <= radius + 1e-12
        assert inside.all(), (shape.link, shape.kind)


def test_when_segments_are_measured_expect_the_brute_force_distance():
    """Crossing, parallel, collinear and zero-length segments (spheres) alike."""
    rng = np.random.default_rng(3)
    a0, a1, b0, b1 = rng.normal(size=(4, 300, 3))
    a1[:100] = a0[:100]  # points
    b1[50:150] = b0[50:150]
    b1[200:260] = b0[200:260] + (a1[200:260] - a0[200:260])  # parallel
    b0[260:300], b1[260:300] = a0[260:300] + 0.3 * (a1[260:300] - a0[260:300]), a1[260:300] * 2
    fine = np.linspace(0.0, 1.0, 401)[:, None]
    brute = np.empty(len(a0))
    for i in range(len(a0)):  # the closest of 401 x 401 points along the two segments
        on_a, on_b = a0[i] + fine * (a1[i] - a0[i]), b0[i] + fine * (b1[i] - b0[i])
        brute[i] = np.linalg.norm(on_a[:, None] - on_b[None], axis=-1).min()
    ours = segment_distances(a0, a1, b0, b1)
    assert np.all(ours <= brute + 1e-12)  # never more than a sampled pair of points
    assert np.abs(ours - brute).max() < 1e-2  # the sampling's own step (1/400 of a segment)


def test_when_a_pose_is_not_finite_or_of_the_wrong_size_expect_a_clear_error(capsules, robot):
    for bad in (np.full(robot.n_joints, np.nan), np.array([np.inf] * robot.n_joints)):
        with pytest.raises(ValueError, match="finite"):
            capsules.clearance(bad)
    with pytest.raises(ValueError, match="n_joints"):
        capsules.clearance(np.zeros(robot.n_joints + 1))


def test_when_a_shape_is_a_mesh_or_a_joint_is_missing_expect_a_capsule_model_error(robot, tmp_path):
    text = RobotKinematics().urdf_xml
    meshed = tmp_path / "meshed.urdf"
    meshed.write_text(text.replace('<sphere radius="0.105"/>', '<mesh filename="head.stl"/>'))
    with pytest.raises(CapsuleModelError, match="mesh"):
        CapsuleModel(robot, meshed)
    renamed = replace(
        robot, joints=(*robot.joints[:-1], replace(robot.joints[-1], name="NoSuchJoint"))
    )
    with pytest.raises(CapsuleModelError, match="NoSuchJoint"):
        CapsuleModel(renamed)


def test_when_the_packaged_model_streams_expect_neither_pinocchio_nor_coal_in_its_process():
    """The inference node's process samples with the capsules: no exact model's libraries.

    In a process of its own, so that no other test's imports count.
    """
    script = textwrap.dedent(
        """
        import sys
        import numpy as np
        import rclpy
        from audio2pose_ros.checkpoints.numpy_runtime import load_streaming_model
        from audio2pose_ros.resources import default_checkpoint_path
        from audio2pose_ros.robot.description import load_robot
        from audio2pose_ros.ros.nodes.inference_node import InferenceNode
        from audio2pose_ros.ros.player import rclpy_session

        model = load_streaming_model(default_checkpoint_path(), robot=load_robot())
        predictor = model.predictor(seed=0)
        rng = np.random.default_rng(0)
        frames = model.normalizer.mean + rng.normal(size=(200, model.normalizer.mean.size))
        poses = [predictor.step(frame) for frame in frames]
        assert np.isfinite(poses).all()
        with rclpy_session():
            node = InferenceNode()
            node.destroy_node()
        loaded = sorted(m for m in ("pinocchio", "coal", "hppfcl", "eigenpy") if m in sys.modules)
        print("loaded:", loaded)
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=300, check=False
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "loaded: []" in done.stdout, done.stdout


def test_when_pairs_are_measured_one_pose_at_a_time_expect_the_batched_distances(
    capsules, random_poses
):
    """Any choice of pairs in one pose: the distances of pair_distances, to the last bit."""
    one = pickle.loads(pickle.dumps(capsules.one_pose()))  # a sampler pickles with it
    every = np.arange(len(capsules.link_pairs))
    rng = np.random.default_rng(1)
    poses = random_poses[:300]
    for pose, expected in zip(poses, capsules.pair_distances(poses), strict=True):
        one.place(pose)
        pairs = rng.choice(every, rng.integers(1, 60), replace=False)
        assert np.array_equal(one.distances(pairs), expected[pairs])
        assert np.array_equal(one.distances(every), expected)
    revived = pickle.loads(pickle.dumps(one))  # mid-sequence: the pose placed goes along
    assert np.array_equal(revived.distances(every), one.distances(every))

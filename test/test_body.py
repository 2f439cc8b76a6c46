"""robot/body.py: Pepper's collision shapes, the checked pairs and clearance queries."""

from __future__ import annotations

import numpy as np
import pytest
from body_poses import pose_with

from audio2pose_ros.robot.body import BodyModel, BodyModelError
from audio2pose_ros.robot.pairs import ARM_LINK_PREFIXES, SHOULDER_LINKS, checked_pair

MARGIN_M = 0.02


@pytest.fixture(scope="module")
def body():
    return BodyModel.load()


def random_poses(robot, n, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(robot.lower_rad, robot.upper_rad, size=(n, robot.n_joints))


def test_when_neutral_pose_expect_clear_of_the_body_by_the_default_margin(body):
    assert body.clearance(body.robot.neutral_rad) >= MARGIN_M


def test_when_left_forearm_folded_into_the_tablet_expect_negative_clearance_naming_links(body):
    pose = pose_with(
        body.robot, LShoulderPitch=1.22, LShoulderRoll=0.04, LElbowRoll=-1.32, LElbowYaw=-0.19
    )
    distance, arm_link, other = body.closest_pair(pose)
    assert distance < -0.05  # the forearm is 6 cm inside the torso and tablet
    assert (arm_link, other) == ("LForeArm", "torso")


def test_when_chest_tablet_expect_a_collision_shape_in_front_of_the_torso(body):
    """The tablet is solid: a hand pressed onto the chest's front is inside the body."""
    pin = pytest.importorskip("pinocchio")
    model = pin.buildModelFromUrdf(str(body.urdf_path))
    geometry = pin.buildGeomFromUrdf(model, str(body.urdf_path), pin.GeometryType.COLLISION)
    boxes = [
        obj
        for obj in geometry.geometryObjects
        if obj.name.startswith("torso") and type(obj.geometry).__name__ == "Box"
    ]
    assert boxes, "the torso has no box (the tablet)"
    front = max(box.placement.translation[0] + box.geometry.halfSide[0] for box in boxes)
    assert front > 0.09  # beyond the torso cylinder's front surface (x = 0.09 m)


def test_when_sampled_expect_every_checked_pair_to_move_with_some_command(body):
    """Pairs whose distance no command changes are not checked (allowed-collision matrix)."""
    poses = random_poses(body.robot, 200)
    distances = np.array([body.pair_distances(pose) for pose in poses])
    assert np.all(distances.std(axis=0) > 1e-6), [
        pair for pair, s in zip(body.link_pairs, distances.std(axis=0), strict=True) if s <= 1e-6
    ]


def test_when_shoulder_balls_are_excluded_expect_the_head_never_near_them(body):
    """The shoulder balls turn in place; only the head could approach them, and cannot."""
    pin = pytest.importorskip("pinocchio")
    model = pin.buildModelFromUrdf(str(body.urdf_path))
    geometry = pin.buildGeomFromUrdf(model, str(body.urdf_path), pin.GeometryType.COLLISION)
    names = [obj.name for obj in geometry.geometryObjects]
    shoulders = [i for i, n in enumerate(names) if n.rsplit("_", 1)[0] in SHOULDER_LINKS.values()]
    heads = [i for i, n in enumerate(names) if n.startswith(("Head", "Neck"))]
    for a in shoulders:
        for b in heads:
            geometry.addCollisionPair(pin.CollisionPair(a, b))
    data, geometry_data = model.createData(), geometry.createData()
    q = pin.neutral(model)
    closest = np.inf
    for pose in random_poses(body.robot, 300, seed=1):
        for i, name in enumerate(body.robot.names):
            q[model.joints[model.getJointId(name)].idx_q] = pose[i]
        pin.computeDistances(model, data, geometry, geometry_data, q)
        closest = min(closest, min(r.min_distance for r in geometry_data.distanceResults))
    assert closest > MARGIN_M


def test_when_many_poses_expect_clearance_equal_to_the_smallest_pair_distance(body):
    poses = random_poses(body.robot, 50, seed=2)
    expected = np.array([body.pair_distances(pose).min() for pose in poses])
    np.testing.assert_allclose(body.clearance(poses), expected, atol=1e-6)
    assert body.clearance(poses[0]).shape == ()


def test_when_other_poses_were_queried_since_expect_pair_distances_of_the_asked_pose(body):
    """A pose asked again is answered from the cache of its smallest distance only."""
    first, second = random_poses(body.robot, 2, seed=4)
    body.clearance(first)
    fresh = body.pair_distances(first)
    body.clearance(second)
    np.testing.assert_allclose(body.pair_distances(first), fresh, atol=1e-5)  # coal: 1e-6 m
    assert body.pair_distances(first).min() == pytest.approx(float(body.clearance(first)), abs=1e-5)


def test_when_one_pair_is_closest_expect_gradient_of_the_whole_clearance(body):
    """The gradient queries the closest pair only: it must be the clearance's own."""
    step = 1e-3
    compared = 0
    for pose in random_poses(body.robot, 40, seed=5):
        distances = np.sort(body.pair_distances(pose))
        if distances[1] - distances[0] < 0.01:  # another pair as close: the minimum may switch
            continue
        joints = np.ones(body.robot.n_joints, dtype=bool)
        expected = np.zeros(body.robot.n_joints)
        for i in range(body.robot.n_joints):
            up, down = pose.copy(), pose.copy()
            up[i] += step
            down[i] -= step
            expected[i] = (body.pair_distances(up).min() - body.pair_distances(down).min()) / (
                2 * step
            )
        # coal answers within 1e-6 m, so a 1e-3 rad difference is good to about 1e-3 m/rad
        np.testing.assert_allclose(body.gradient(pose, joints), expected, atol=2e-3)
        compared += 1
    assert compared >= 20


def test_when_poses_inside_expect_push_out_clears_them_moving_only_the_offending_arm(body):
    poses = random_poses(body.robot, 60, seed=3)
    inside = poses[body.clearance(poses) < MARGIN_M]
    assert len(inside) > 5
    pushed = body.push_out(inside, MARGIN_M)
    assert np.all(body.clearance(pushed) >= MARGIN_M - 1e-9)
    assert np.all(pushed >= body.robot.lower_rad)
    assert np.all(pushed <= body.robot.upper_rad)
    clear = poses[body.clearance(poses) >= MARGIN_M]
    np.testing.assert_array_equal(body.push_out(clear, MARGIN_M), clear)


def test_when_only_left_hand_in_hip_expect_right_arm_and_head_unchanged_by_push_out(body):
    robot = body.robot
    pose = pose_with(
        robot, LShoulderPitch=1.3, LShoulderRoll=0.13, LElbowRoll=-1.24, LElbowYaw=0.28, HeadYaw=0.5
    )
    clearance, joints = body.violations(pose, MARGIN_M)
    assert clearance < MARGIN_M
    pushed = body.push_out(pose, MARGIN_M)
    untouched = [robot.names.index(n) for n in ("HeadYaw", "HeadPitch", "RShoulderPitch")]
    np.testing.assert_array_equal(pushed[untouched], pose[untouched])
    assert not joints[untouched].any()


@pytest.mark.parametrize(
    "bad", [np.full(11, np.nan), np.zeros(10), np.zeros((2, 3, 11)), np.full(11, np.inf)]
)
def test_when_pose_malformed_expect_value_error(body, bad):
    with pytest.raises(ValueError, match="poses must be"):
        body.clearance(bad)


def test_when_urdf_lacks_a_joint_expect_a_configuration_error_naming_it(body, tmp_path):
    urdf = tmp_path / "pepper.urdf"
    urdf.write_text(body.urdf_path.read_text().replace('name="HipRoll"', 'name="HipTilt"'))
    with pytest.raises(BodyModelError, match="HipRoll"):
        BodyModel.load(urdf_path=urdf)


def test_when_joints_turn_expect_clearance_to_change_no_more_than_the_lever_bound(body):
    """The body-noise model bounds how near the arms can have come with lever_m: the bound must
    hold for any pair of poses."""
    rng = np.random.default_rng(4)
    poses = random_poses(body.robot, 200, seed=5)
    moved = np.clip(
        poses + rng.normal(scale=0.3, size=poses.shape), body.robot.lower_rad, body.robot.upper_rad
    )
    change = np.abs(body.clearance(moved) - body.clearance(poses))
    bound = np.abs(moved - poses) @ body.lever_m
    assert np.all(change <= bound + 1e-6)
    assert np.max(change / bound) > 0.1  # a bound, but not a vacuous one


def test_when_joints_turn_expect_each_pair_to_move_no_more_than_its_own_lever_bound(body):
    """The guard's sweep skips queries with pair_lever_m (only the joints that move one shape of
    a pair and not the other count): that bound must hold for every pair and any two poses."""
    rng = np.random.default_rng(6)
    poses = random_poses(body.robot, 60, seed=7)
    moved = np.clip(
        poses + rng.normal(scale=0.3, size=poses.shape), body.robot.lower_rad, body.robot.upper_rad
    )
    ratios = []
    for pose, other in zip(poses, moved, strict=True):
        change = np.abs(body.pair_distances(other) - body.pair_distances(pose))
        bound = body.pair_lever_m @ np.abs(other - pose)
        assert np.all(change <= bound + 1e-6)
        ratios.append(np.max(change / np.maximum(bound, 1e-9)))
    assert max(ratios) > 0.1  # a bound, but not a vacuous one
    hip = body.robot.names.index("HipRoll")
    arm_torso = [k for k, pair in enumerate(body.link_pairs) if pair[1] == "torso"]
    assert np.all(body.pair_lever_m[arm_torso, hip] == 0.0)  # the hip turns arm and torso alike


def test_when_a_path_crosses_a_thin_part_between_two_clear_poses_expect_the_sweep_to_find_it(
    body,
):
    """Two clear poses whose straight way passes the body: the ends alone look clear, the
    sweep of the densely sampled way finds the crossing; a clear way passes, with a lower
    bound of its clearance no higher than any of its points."""
    robot = body.robot
    a = np.array([0.28, 0.51, 0.31, 2.0, -1.46, 1.04, -0.82, 0.96, 0.49, 1.83, -0.3])
    b = np.array([-0.51, -0.73, 0.39, -0.31, -0.44, -1.87, -0.35, 1.58, 0.13, 1.01, 0.11])
    way = a + np.linspace(0.0, 1.0, 400)[:, None] * (b - a)
    assert min(body.clearance(a), body.clearance(b)) > 0.02
    crossing = body.sweep(way, 0.02)
    assert not crossing.clear
    assert body.clearance(way[crossing.index]) < 0.02
    assert body.clearance(way[: crossing.index]).min() >= 0.02
    clear = robot.neutral_rad + np.linspace(0.0, 0.1, 50)[:, None] * np.ones(robot.n_joints)
    found = body.sweep(clear, 0.02)
    assert found.clear
    assert found.lowest_m <= body.clearance(clear).min()
    assert found.queries < len(clear)  # most of a way far from the body needs no query


def test_when_a_path_is_given_as_sampled_pieces_expect_the_sweep_of_its_samples(body):
    """The guard gives the sweep its path's corners and each piece's sample count (it makes only
    the samples it queries): that must find what the sweep of every sample finds, at the same
    sample, and bound a clear path's clearance no higher than any of its samples."""
    a = np.array([0.28, 0.51, 0.31, 2.0, -1.46, 1.04, -0.82, 0.96, 0.49, 1.83, -0.3])
    b = np.array([-0.51, -0.73, 0.39, -0.31, -0.44, -1.87, -0.35, 1.58, 0.13, 1.01, 0.11])
    c = body.robot.neutral_rad
    for corners, counts, floor in (
        (np.array([a, b]), np.array([399]), 0.02),
        (np.array([a, 0.5 * (a + b), b]), np.array([150, 250]), 0.02),
        (np.array([c, a, c, a]), np.array([80, 3, 120]), 0.0),
    ):
        samples = [corners[:1]]
        for start, end, count in zip(corners[:-1], corners[1:], counts, strict=True):
            samples.append(start + (np.arange(1, count + 1) / count)[:, None] * (end - start))
        dense = np.vstack(samples)
        body.reset()
        pieces = body.sweep(corners, floor, counts)
        body.reset()
        every = body.sweep(dense, floor)
        assert (pieces.clear, pieces.index, pieces.pair) == (every.clear, every.index, every.pair)
        assert pieces.queries == every.queries  # at the same samples: each first one in reach
        if pieces.clear:
            assert pieces.lowest_m <= body.clearance(dense).min()
            assert pieces.queries < len(dense)
        else:
            assert body.clearance(dense[pieces.index]) < floor
            assert body.clearance(dense[: pieces.index]).min() >= floor


def _pinocchio_reference(body):
    """Pinocchio's kinematic and collision models of the same URDF, with the checked pairs.

    Pinocchio loaded the body model until numpy forward kinematics replaced it (it held about
    21 MB of the motion filter's process): it is the reference the model must still match.
    """
    pin = pytest.importorskip("pinocchio")
    model = pin.buildModelFromUrdf(str(body.urdf_path))
    geometry = pin.buildGeomFromUrdf(model, str(body.urdf_path), pin.GeometryType.COLLISION)
    links = [obj.name.rsplit("_", 1)[0] for obj in geometry.geometryObjects]
    pairs = [
        (a, b)
        for a in range(len(links))
        for b in range(len(links))
        if a != b and checked_pair(links[a], links[b])
    ]
    for a, b in pairs:
        geometry.addCollisionPair(pin.CollisionPair(a, b))
    q_index = [model.joints[model.getJointId(name)].idx_q for name in body.robot.names]

    def configuration(pose):
        q = pin.neutral(model)
        q[q_index] = pose
        return q

    return pin, model, geometry, links, pairs, configuration


def _random_walk(robot, n, seed, step_rad=0.02):
    """Poses a small step apart (as commands are), within the joint limits."""
    rng = np.random.default_rng(seed)
    poses = [rng.uniform(robot.lower_rad, robot.upper_rad)]
    for _ in range(n - 1):
        step = rng.normal(scale=step_rad, size=robot.n_joints)
        poses.append(np.clip(poses[-1] + step, robot.lower_rad, robot.upper_rad))
    return np.array(poses)


def test_when_shapes_and_links_are_placed_expect_pinocchios_placements(body):
    """The numpy forward kinematics puts every collision shape (in Pinocchio's order) and the
    links the wrist measures use where Pinocchio does, in random poses within the limits."""
    pin, model, geometry, links, _, configuration = _pinocchio_reference(body)
    assert body.shape_links == tuple(links)
    data, geometry_data = model.createData(), geometry.createData()
    poses = random_poses(body.robot, 40, seed=11)
    placed = body.placements(poses)
    torso = model.getFrameId("torso")
    for pose, ours in zip(poses, placed, strict=True):
        pin.forwardKinematics(model, data, configuration(pose))
        pin.updateGeometryPlacements(model, data, geometry, geometry_data)
        pin.updateFramePlacements(model, data)
        theirs = np.array([placement.homogeneous for placement in geometry_data.oMg])
        np.testing.assert_allclose(ours, theirs, rtol=0.0, atol=1e-9)
        for link, wrist in zip(("l_wrist", "r_wrist"), body.wrist_positions(pose)[0], strict=True):
            at = data.oMf[torso].actInv(data.oMf[model.getFrameId(link)]).translation
            np.testing.assert_allclose(wrist, at, rtol=0.0, atol=1e-9)


def test_when_pairs_are_measured_along_a_path_expect_pinocchios_distances_and_levers(body):
    """Every pair's distance along a path of small steps is the one Pinocchio's
    computeDistances gives for the same poses in the same order (coal starts each search from
    the pair's previous answer, so the order counts), to coal's tolerance; the checked pairs,
    their joints and the lever bounds are the ones computed from Pinocchio's model."""
    pin, model, geometry, links, pairs, configuration = _pinocchio_reference(body)
    assert body.link_pairs == tuple((links[a], links[b]) for a, b in pairs)
    data, geometry_data = model.createData(), geometry.createData()
    body.reset()
    for pose in _random_walk(body.robot, 120, seed=12):
        pin.computeDistances(model, data, geometry, geometry_data, configuration(pose))
        theirs = np.array([result.min_distance for result in geometry_data.distanceResults])
        # coal answers within 1e-6 m: the shapes' placements differ from Pinocchio's in their
        # last bits (1e-16 m), which can end a search one step sooner or later
        np.testing.assert_allclose(body.pair_distances(pose), theirs, rtol=0.0, atol=1e-6)
    body.reset()
    # levers from Pinocchio's joint tree: bounding radius, shape offset, joint offsets below
    ids = [model.getJointId(name) for name in body.robot.names]
    levers = np.zeros((len(links), body.robot.n_joints))
    for s, obj in enumerate(geometry.geometryObjects):
        shape = obj.geometry
        radius = {
            "Sphere": lambda g: g.radius,
            "Cylinder": lambda g: np.hypot(g.radius, g.halfLength),
            "Box": lambda g: np.linalg.norm(g.halfSide),
        }[type(shape).__name__](shape) + np.linalg.norm(obj.placement.translation)
        chain = [int(j) for j in model.supports[obj.parentJoint]]
        for i, joint in enumerate(ids):
            if joint in chain:
                below = chain[chain.index(joint) + 1 :]
                offsets = [np.linalg.norm(model.jointPlacements[j].translation) for j in below]
                levers[s, i] = radius + sum(offsets)
    np.testing.assert_allclose(body.lever_m, levers.max(axis=0), rtol=0.0, atol=1e-12)
    moved = levers > 0.0
    for k, (a, b) in enumerate(pairs):
        expected = np.where(moved[a] & ~moved[b], levers[a], 0.0) + np.where(
            moved[b] & ~moved[a], levers[b], 0.0
        )
        np.testing.assert_allclose(body.pair_lever_m[k], expected, rtol=0.0, atol=1e-12)
        hand = {link: arm[-1] for arm in ARM_LINK_PREFIXES.values() for link in arm}
        supports = set()
        for shape in (a, b):
            link = hand.get(links[shape], links[shape])
            joint = geometry.geometryObjects[links.index(link)].parentJoint
            supports |= {model.names[int(j)] for j in model.supports[joint]}
        np.testing.assert_array_equal(
            body.pair_joints(k), [name in supports for name in body.robot.names]
        )


def test_when_only_the_pairs_that_can_be_closest_are_measured_expect_the_closest_of_all(body):
    """A query measures only the pairs whose lever bound can undercut the closest one: along
    paths of small steps and of jumps, its answer is the closest of every pair measured afresh
    (coal's 1e-6 m), the same pair wherever no other is that close."""
    compared = 0
    for poses in (_random_walk(body.robot, 150, seed=13), random_poses(body.robot, 40, seed=14)):
        body.reset()
        answers = [body.query(pose) for pose in poses]
        body.reset()
        for pose, (distance, pair) in zip(poses, answers, strict=True):
            every = body.pair_distances(pose)
            assert distance == pytest.approx(every.min(), abs=2e-6)
            if np.partition(every, 1)[1] - every.min() > 1e-5:
                assert pair == int(np.argmin(every))
                compared += 1
    assert compared > 150

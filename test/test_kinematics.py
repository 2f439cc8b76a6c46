"""Forward kinematics of urdf/pepper.urdf: where the head and hands are, and where they go."""

import sys

import numpy as np
import pytest

from audio2pose_ros.robot.description import load_robot
from audio2pose_ros.robot.kinematics import (
    DrivenFrames,
    KinematicsError,
    RobotKinematics,
    axis_angle_matrix,
)
from audio2pose_ros.robot.urdf_outline import outline, parse_apart, read_outline


@pytest.fixture(scope="module")
def kinematics():
    return RobotKinematics()


@pytest.fixture(scope="module")
def neutral():
    robot = load_robot()
    return dict(zip(robot.names, robot.neutral_rad.tolist(), strict=True))


def position(kinematics, positions, link, frame=None):
    poses = kinematics.link_poses(positions)
    pose = poses[link] if frame is None else np.linalg.inv(poses[frame]) @ poses[link]
    return pose[:3, 3]


def test_when_rotating_about_z_by_a_quarter_turn_expect_x_onto_y():
    rotation = axis_angle_matrix(np.array([0.0, 0.0, 1.0]), np.pi / 2)
    np.testing.assert_allclose(rotation @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-12)


def test_when_in_neutral_pose_expect_head_above_torso_and_hands_below_shoulders(
    kinematics, neutral
):
    head = position(kinematics, neutral, "Head")
    torso = position(kinematics, neutral, "torso")
    assert head[2] > torso[2] + 0.15
    for side, sign in (("l", 1), ("r", -1)):
        hand = position(kinematics, neutral, f"{side}_gripper")
        shoulder = position(kinematics, neutral, f"{side.upper()}Shoulder")
        assert hand[2] < shoulder[2] - 0.2
        assert sign * hand[1] > 0.1


def test_when_head_yaw_is_positive_expect_the_face_turns_to_the_left(kinematics, neutral):
    straight = kinematics.link_poses(neutral)["Head"][:3, 0]
    turned = kinematics.link_poses({**neutral, "HeadYaw": 0.5})["Head"][:3, 0]
    assert abs(straight[1]) < 1e-9
    assert turned[1] == pytest.approx(np.sin(0.5) * straight[0])  # the horizontal part turns


def test_when_head_pitch_is_positive_expect_the_face_looks_down(kinematics, neutral):
    down = kinematics.link_poses({**neutral, "HeadPitch": 0.4})["Head"][:3, 0]
    up = kinematics.link_poses({**neutral, "HeadPitch": -0.6})["Head"][:3, 0]
    assert down[2] < 0 < up[2]


def test_when_left_shoulder_pitch_decreases_expect_the_left_hand_forward_and_up(
    kinematics, neutral
):
    hand = [
        position(kinematics, {**neutral, "LShoulderPitch": pitch}, "l_gripper")
        for pitch in (np.pi / 2, 0.8, 0.0)
    ]
    assert hand[0][2] < hand[1][2] < hand[2][2]
    assert hand[0][0] < hand[2][0]
    right = position(kinematics, {**neutral, "LShoulderPitch": 0.0}, "r_gripper")
    np.testing.assert_allclose(right, position(kinematics, neutral, "r_gripper"))


def test_when_shoulder_roll_opens_expect_each_hand_moves_outwards(kinematics, neutral):
    left = position(kinematics, {**neutral, "LShoulderRoll": 1.0}, "l_gripper")
    right = position(kinematics, {**neutral, "RShoulderRoll": -1.0}, "r_gripper")
    assert left[1] > position(kinematics, neutral, "l_gripper")[1] + 0.1
    assert right[1] < position(kinematics, neutral, "r_gripper")[1] - 0.1


def test_when_hip_roll_changes_expect_the_upper_body_tilts_sideways_over_the_base(
    kinematics, neutral
):
    upright = position(kinematics, neutral, "Head", frame="Tibia")
    left = position(kinematics, {**neutral, "HipRoll": 0.4}, "Head", frame="Tibia")
    right = position(kinematics, {**neutral, "HipRoll": -0.4}, "Head", frame="Tibia")
    assert abs(upright[1]) < 1e-9
    assert left[1] > 0.08
    assert right[1] < -0.08
    assert left[2] < upright[2]


def test_when_a_joint_is_left_out_expect_its_default_inside_its_limits(kinematics):
    positions = kinematics.resolve({})
    assert positions["LHand"] == pytest.approx(0.02)
    assert positions["HeadYaw"] == 0.0


def test_when_naming_an_unknown_joint_expect_an_error_naming_it(kinematics):
    with pytest.raises(KinematicsError, match="Elbow2"):
        kinematics.link_poses({"Elbow2": 0.1})


def test_when_the_urdf_is_read_expect_the_joints_yourdfpy_reads(kinematics):
    """The standard library's XML parser reads what an independent URDF library reads."""
    yourdfpy = pytest.importorskip("yourdfpy")
    reference = yourdfpy.URDF.load(
        str(kinematics.urdf_path), build_scene_graph=False, load_meshes=False
    )
    theirs = {joint.name: joint for joint in reference.robot.joints}
    assert sorted(theirs) == sorted(j.name for j in kinematics.joints)
    for joint in kinematics.joints:
        other = theirs[joint.name]
        assert (joint.joint_type, joint.parent, joint.child) == (
            other.type,
            other.parent,
            other.child,
        )
        np.testing.assert_allclose(joint.origin, other.origin, atol=1e-12)
        if other.limit is not None:
            assert joint.lower_rad == (other.limit.lower or 0.0)
            assert joint.upper_rad == (other.limit.upper or 0.0)
    collisions = [(link.name, c) for link in reference.robot.links for c in link.collisions]
    assert len(kinematics.collisions) == len(collisions)
    for ours, (link, theirs_shape) in zip(kinematics.collisions, collisions, strict=True):
        geometry = theirs_shape.geometry
        assert ours.link == link
        if ours.kind == "box":
            np.testing.assert_allclose(ours.size, geometry.box.size)
        elif ours.kind == "cylinder":
            assert ours.size == (geometry.cylinder.radius, geometry.cylinder.length)
        else:
            assert ours.size == (geometry.sphere.radius,)
        np.testing.assert_allclose(ours.origin, theirs_shape.origin, atol=1e-12, err_msg=link)


def test_when_links_are_placed_expect_pinocchios_placements(kinematics):
    """Forward kinematics against an independent one (Pinocchio's, on the same file)."""
    pin = pytest.importorskip("pinocchio")
    model = pin.buildModelFromUrdf(str(kinematics.urdf_path))
    data = model.createData()
    rng = np.random.default_rng(0)
    names = kinematics.movable_joint_names
    for _ in range(20):
        positions = {
            name: float(
                rng.uniform(kinematics.joint(name).lower_rad, kinematics.joint(name).upper_rad)
            )
            for name in names
        }
        q = pin.neutral(model)
        for name, value in positions.items():
            q[model.joints[model.getJointId(name)].idx_q] = value
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)
        ours = kinematics.link_poses(positions)
        for link in kinematics.link_names:
            np.testing.assert_allclose(
                ours[link], data.oMf[model.getFrameId(link)].homogeneous, atol=1e-9, err_msg=link
            )


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ('<robot name="pepper">', "<robot", "cannot parse"),
        ('<origin xyz="-0.038 0 0.1699" rpy="0 0 0"/>', '<origin xyz="nan 0 0.1699"/>', "finite"),
        (
            '<origin xyz="-0.038 0 0.1699" rpy="0 0 0"/>',
            '<origin xyz="0 0.1699"/>',
            "vector length",
        ),
        ('<axis xyz="0 0 1"/>', '<axis xyz="0 0 0"/>', "zero axis"),
        ('<joint name="HeadYaw" type="revolute">', '<joint name="HeadYaw" type="hinge">', "hinge"),
        ('<sphere radius="0.105"/>', '<sphere radius="-0.105"/>', "size"),
        ('<parent link="torso"/>', "", "parent"),
    ],
)
@pytest.mark.parametrize("apart", [False, True], ids=["here", "child-process"])
def test_when_the_urdf_is_malformed_expect_a_kinematics_error_naming_it(
    kinematics, tmp_path, old, new, message, apart
):
    assert old in kinematics.urdf_xml
    broken = tmp_path / "broken.urdf"
    broken.write_text(kinematics.urdf_xml.replace(old, new))
    parse_apart(apart)
    try:
        with pytest.raises(KinematicsError, match=message):
            RobotKinematics(broken)
    finally:
        parse_apart(False)


def test_when_parsed_in_a_child_process_expect_what_this_process_reads(kinematics):
    """A node process's URDF parse (in a child) gives the same outline and the same model."""
    parse_apart(True)
    try:
        apart = RobotKinematics(kinematics.urdf_path)
        outline_apart = read_outline(kinematics.urdf_xml)
    finally:
        parse_apart(False)
    assert outline_apart == outline(kinematics.urdf_xml)
    for a, b in zip(apart.joints, kinematics.joints, strict=True):
        assert (a.name, a.joint_type, a.parent, a.child) == (
            b.name,
            b.joint_type,
            b.parent,
            b.child,
        )
        assert (a.lower_rad, a.upper_rad, a.max_velocity_rad_s) == (
            b.lower_rad,
            b.upper_rad,
            b.max_velocity_rad_s,
        )
        np.testing.assert_array_equal(a.origin, b.origin)
        np.testing.assert_array_equal(a.axis, b.axis)
    assert [(c.link, c.kind, c.size) for c in apart.collisions] == [
        (c.link, c.kind, c.size) for c in kinematics.collisions
    ]
    for a, b in zip(apart.collisions, kinematics.collisions, strict=True):
        np.testing.assert_array_equal(a.origin, b.origin)


def test_when_no_interpreter_can_be_started_expect_the_urdf_parsed_here(
    kinematics, monkeypatch, tmp_path
):
    monkeypatch.setattr(sys, "executable", str(tmp_path / "no-python"))
    parse_apart(True)
    try:
        assert read_outline(kinematics.urdf_xml) == outline(kinematics.urdf_xml)
    finally:
        parse_apart(False)


def test_when_the_parser_process_fails_expect_a_kinematics_error(kinematics, monkeypatch):
    monkeypatch.setattr(sys, "executable", "/bin/false")
    parse_apart(True)
    try:
        with pytest.raises(KinematicsError, match="parser process failed"):
            RobotKinematics(kinematics.urdf_path)
    finally:
        parse_apart(False)


@pytest.mark.parametrize(
    "names",
    [
        tuple(load_robot().names),  # the body model's
        # HeadPitch's and RShoulderRoll's parents (HeadYaw's, RShoulderPitch's frames) are not
        # consecutive frames: the one-pose placer gathers them
        ("RShoulderRoll", "HeadYaw", "LShoulderPitch", "RShoulderPitch", "HeadPitch"),
    ],
)
def test_when_frames_are_placed_one_pose_at_a_time_expect_the_batched_placements(kinematics, names):
    """The one-pose placer gives what place gives (bitwise) and what link_poses gives."""
    driven = DrivenFrames(kinematics, names)
    links = [link for link in kinematics.link_names if link != kinematics.root_link]
    frames = np.array([driven.frame_of[link] for link in links])
    offsets = np.array([driven.link_in_frame[link] for link in links])
    placer = driven.placer(frames, offsets)
    rng = np.random.default_rng(1)
    for _ in range(20):
        pose = np.array(
            [
                rng.uniform(kinematics.joint(n).lower_rad, kinematics.joint(n).upper_rad)
                for n in names
            ]
        )
        placed = placer.place(pose)
        assert np.array_equal(placed, driven.place(pose[None], frames, offsets)[0])
        positions = dict.fromkeys(kinematics.movable_joint_names, 0.0)
        positions.update(zip(names, pose.tolist(), strict=True))
        poses = kinematics.link_poses(positions)
        np.testing.assert_allclose(placed, [poses[link] for link in links], atol=1e-12)

"""``audio2pose render``: MP4 with the audio, a Foxglove bag, side by side, from a recorded bag."""

import argparse
import re
import subprocess

import imageio_ffmpeg
import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from scipy.io import wavfile

from audio2pose_ros.cli.render_commands import register
from audio2pose_ros.data.bag import BagWriter, typestore
from audio2pose_ros.data.dataset import Clip, ClipInfo, Dataset
from audio2pose_ros.errors import UsageError
from audio2pose_ros.offline.trajectory import bag_trajectory
from audio2pose_ros.resources import bundled_speech_path
from audio2pose_ros.robot.description import load_robot
from audio2pose_ros.robot.kinematics import RobotKinematics
from audio2pose_ros.timebase import complete_frames
from audio2pose_ros.topics import AUDIO, JOINT_STATES, absolute
from audio2pose_ros.viz.render import BACKGROUND_RGB, TITLE_HEIGHT_PX, RobotCamera

SMALL = ["--view-width", "160", "--view-height", "192", "--curves-height", "120", "--no-progress"]


def render(*argv):
    parser = argparse.ArgumentParser()
    register(parser.add_subparsers(dest="verb", required=True))
    args = parser.parse_args(["render", *map(str, argv)])
    return args.func(args)


def speech(path, seconds):
    rate, samples = wavfile.read(bundled_speech_path())
    if seconds > len(samples) / rate:  # the 10 s clip: two bundled clips one after the other
        rate, more = wavfile.read(bundled_speech_path("librivox_sense_and_sensibility_01_0880.wav"))
        samples = np.concatenate([samples, more])
    wavfile.write(path, rate, samples[: round(seconds * rate)])
    return path


def probe(path):
    """(duration_s, stream descriptions) as ffmpeg reports them, and the decoded frame count."""
    info = subprocess.run(
        [imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-i", str(path)],
        capture_output=True,
        text=True,
        check=False,
    ).stderr
    hours, minutes, seconds = re.search(r"Duration: (\d+):(\d+):([\d.]+)", info).groups()
    streams = re.findall(r"Stream #\S+.*?: (Video|Audio): (.*)", info)
    n_frames, _ = imageio_ffmpeg.count_frames_and_secs(str(path))
    return 3600 * int(hours) + 60 * int(minutes) + float(seconds), dict(streams), n_frames


def first_frame(path):
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    width, height = meta["size"]
    frame = np.frombuffer(next(reader), dtype=np.uint8).reshape(height, width, 3)
    reader.close()
    return frame


@pytest.fixture(scope="module")
def short_render(tmp_path_factory):
    folder = tmp_path_factory.mktemp("render")
    wav = speech(folder / "speech.wav", 2.5)
    assert render(wav, "-o", folder / "clip.mp4", *SMALL) == 0
    return folder


def test_when_rendering_a_short_clip_expect_mp4_of_its_duration_with_an_audio_stream(
    short_render,
):
    duration_s, streams, n_frames = probe(short_render / "clip.mp4")
    assert duration_s == pytest.approx(2.5, abs=0.08)
    assert n_frames == round(2.5 * 25)
    assert "h264" in streams["Video"]
    assert "160x" in streams["Video"]
    assert "aac" in streams["Audio"]
    assert "16000 Hz" in streams["Audio"]


def test_when_rendering_expect_the_robot_drawn_on_the_background(short_render):
    frame = first_frame(short_render / "clip.mp4").astype(int)
    robot_panel = frame[TITLE_HEIGHT_PX : TITLE_HEIGHT_PX + 192]
    background = np.abs(robot_panel - BACKGROUND_RGB).sum(axis=2) < 30
    assert background[:10, :10].all()  # the corner is empty
    assert 0.05 < 1 - background.mean() < 0.6  # the robot covers part of the view


def test_when_reading_the_bag_with_the_mcap_library_expect_description_joint_states_and_tf(
    short_render,
):
    (mcap_file,) = (short_render / "clip_mcap").glob("*.mcap")
    counts, frames = {}, set()
    with mcap_file.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        channels = {c.topic: c for c in reader.get_summary().channels.values()}
        for _, channel, _, message in reader.iter_decoded_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            if channel.topic == "/robot_description":
                assert message.data.startswith("<?xml")
                assert "<ros2_control" in message.data
            elif channel.topic == "/tf":
                frames |= {(t.header.frame_id, t.child_frame_id) for t in message.transforms}
            else:
                assert "HeadPitch" in message.name
                assert len(message.name) == len(message.position)
    assert set(counts) == {"/robot_description", absolute(JOINT_STATES), "/tf"}
    assert counts["/robot_description"] == 1
    assert counts[absolute(JOINT_STATES)] == counts["/tf"] > 200  # 100 Hz synthesis of 2.5 s
    assert {("base_link", "torso"), ("Neck", "Head"), ("LForeArm", "l_wrist")} <= frames
    qos = yaml.safe_load(channels["/robot_description"].metadata["offered_qos_profiles"])
    assert qos[0]["durability"] == 1  # transient local, as robot_state_publisher offers it


def bag_angles(bag_dir, names):
    """(T, J) positions of ``names`` in a rendered bag's joint states, in message order."""
    (mcap_file,) = bag_dir.glob("*.mcap")
    rows = []
    with mcap_file.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, _, message in reader.iter_decoded_messages():
            if channel.topic == absolute(JOINT_STATES):
                position = dict(zip(message.name, message.position, strict=True))
                rows.append([position[n] for n in names])
    return np.array(rows)


def test_when_rendering_with_a_seed_expect_that_seeds_motion(short_render, tmp_path):
    """The robot runs with any seed; the video shows the motion of the one asked for."""
    from audio2pose_ros.checkpoints.torch_io import load_checkpoint
    from audio2pose_ros.offline.synthesis import synthesize
    from audio2pose_ros.resources import default_checkpoint_path

    wav = short_render / "speech.wav"
    assert render(wav, "-o", tmp_path / "seed3.mp4", "--seed", "3", *SMALL) == 0
    robot = load_robot()
    _, samples = wavfile.read(wav)  # 16 kHz
    audio = samples.astype(np.float32) / 32768
    checkpoint = load_checkpoint(default_checkpoint_path(), robot=robot)
    seeded = bag_angles(tmp_path / "seed3_mcap", robot.names)
    first = bag_angles(short_render / "clip_mcap", robot.names)  # the default seed, 0
    np.testing.assert_allclose(seeded, synthesize(checkpoint, audio, seed=3)[1], atol=1e-6)
    np.testing.assert_allclose(first, synthesize(checkpoint, audio, seed=0)[1], atol=1e-6)
    assert np.abs(seeded - first).max() > 0.01


def test_when_comparing_a_model_with_a_clip_truth_expect_two_robots_side_by_side(tmp_path):
    robot = load_robot()
    rate, samples = wavfile.read(bundled_speech_path())
    audio = samples[: 2 * rate].astype(np.float32) / 32768
    n = complete_frames(len(audio))
    angles = np.tile(robot.neutral_rad, (n, 1))
    angles[:, robot.names.index("LShoulderPitch")] = np.linspace(1.5, 0.0, n)
    dataset = Dataset.create(tmp_path / "data", robot)
    info = ClipInfo("c1", speaker="s", source="test", licence="CC0")
    dataset.add(Clip(info, audio, angles, np.ones_like(angles, dtype=bool)), robot)
    out = tmp_path / "side_by_side.mp4"
    assert render("--data", tmp_path / "data", "--clip", "c1", "-o", out, *SMALL) == 0
    duration_s, streams, _ = probe(out)
    assert duration_s == pytest.approx(2.0, abs=0.08)
    assert "320x" in streams["Video"]  # two 160 px robots


def test_when_the_bag_exists_expect_an_error_before_rendering(tmp_path):
    (tmp_path / "clip_mcap").mkdir()
    wav = speech(tmp_path / "speech.wav", 0.5)
    with pytest.raises(UsageError, match="exists already"):
        render(wav, "-o", tmp_path / "clip.mp4", *SMALL)
    assert not (tmp_path / "clip.mp4").exists()


def test_when_reading_a_recorded_bag_expect_times_from_the_audio_and_angles_by_name(tmp_path):
    robot = load_robot()
    store = typestore()
    msgs = store.types
    start_ns = 1_000_000_000_000
    with BagWriter(tmp_path / "rec") as bag:
        audio = msgs["audio_common_msgs/msg/AudioData"](data=np.zeros(320, dtype=np.uint8))
        bag.write(
            absolute(AUDIO),
            "audio_common_msgs/msg/AudioData",
            start_ns,
            store.serialize_cdr(audio, "audio_common_msgs/msg/AudioData"),
        )
        for i in range(3):
            header = msgs["std_msgs/msg/Header"](
                stamp=msgs["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id=""
            )
            state = msgs["sensor_msgs/msg/JointState"](
                header=header,
                name=["HipRoll", "HeadYaw"],
                position=np.array([0.1 * i, -0.2 * i]),
                velocity=np.zeros(0),
                effort=np.zeros(0),
            )
            bag.write(
                absolute(JOINT_STATES),
                "sensor_msgs/msg/JointState",
                start_ns + (i + 1) * 10_000_000,
                store.serialize_cdr(state, "sensor_msgs/msg/JointState"),
            )
    trajectory = bag_trajectory(tmp_path / "rec", robot)
    np.testing.assert_allclose(trajectory.times_s, [0.01, 0.02, 0.03])
    np.testing.assert_allclose(
        trajectory.angles_rad[:, robot.names.index("HipRoll")], [0, 0.1, 0.2]
    )
    np.testing.assert_allclose(
        trajectory.angles_rad[:, robot.names.index("HeadYaw")], [0, -0.2, -0.4]
    )
    other = robot.names.index("LElbowYaw")
    np.testing.assert_allclose(trajectory.angles_rad[:, other], robot.neutral_rad[other])


def test_when_posing_the_pybullet_model_expect_our_forward_kinematics():
    kinematics = RobotKinematics()
    camera = RobotCamera(kinematics, 64, 64)
    rng = np.random.default_rng(0)
    positions = {
        name: rng.uniform(kinematics.joint(name).lower_rad, kinematics.joint(name).upper_rad)
        for name in kinematics.movable_joint_names
    }
    camera.set_positions(positions)
    ours = kinematics.link_poses(positions)
    theirs = {link: camera.link_pose(link) for link in ("torso", "Head", "l_gripper", "Tibia")}
    camera.close()
    # the wheeled base stays on the floor whatever the hips do
    np.testing.assert_allclose(theirs["Tibia"], kinematics.link_poses({})["Tibia"], atol=1e-6)
    for link in ("Head", "l_gripper", "Tibia"):
        np.testing.assert_allclose(
            np.linalg.inv(theirs["torso"]) @ theirs[link],
            np.linalg.inv(ours["torso"]) @ ours[link],
            atol=1e-6,
            err_msg=link,
        )


@pytest.mark.slow
def test_when_rendering_ten_seconds_of_speech_expect_ten_seconds_of_video_with_audio(tmp_path):
    """The whole clip is rendered (`audio2pose render` prints how long it took)."""
    wav = speech(tmp_path / "ten.wav", 10.0)
    assert render(wav, "-o", tmp_path / "ten.mp4", "--side", "--no-progress") == 0
    duration_s, streams, _ = probe(tmp_path / "ten.mp4")
    assert duration_s == pytest.approx(10.0, abs=0.08)
    assert "Audio" in streams

"""The simulated Pepper's head camera over real DDS: images as naoqi_driver publishes them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from graph_probe import Probe
from naoqi_bridge_msgs.msg import JointAnglesWithSpeed
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image

from audio2pose_ros.ros.messages import stamp_s
from audio2pose_ros.ros.supervisor import NodeSupervisor, executable_command
from audio2pose_ros.topics import CAMERA_IMAGE, CAMERA_INFO, JOINT_ANGLES, absolute

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def red_share(msg: Image) -> float:
    rgb = np.frombuffer(bytes(msg.data), dtype=np.uint8).reshape(msg.height, msg.width, 3)
    rgb = rgb.reshape(-1, 3).astype(int)
    return float(((rgb[:, 0] > 150) & (rgb[:, 1] < 80) & (rgb[:, 2] < 80)).mean())


def test_when_the_simulated_head_turns_expect_its_camera_image_to_follow(
    tmp_path: Path, probe: Probe
) -> None:
    images: list[Image] = []
    infos: list[CameraInfo] = []
    probe.create_subscription(Image, absolute(CAMERA_IMAGE), images.append, qos_profile_sensor_data)
    probe.create_subscription(
        CameraInfo, absolute(CAMERA_INFO), infos.append, qos_profile_sensor_data
    )
    command = probe.create_publisher(JointAnglesWithSpeed, absolute(JOINT_ANGLES), 10)
    supervisor = NodeSupervisor(
        {"pepper_sim_node": executable_command("pepper_sim_node")}, tmp_path
    )
    supervisor.start()
    try:
        probe.wait_until(lambda: len(images) >= 2)
        ahead = len(images)
        turn = JointAnglesWithSpeed(joint_names=["HeadYaw"], joint_angles=[1.0], speed=1.0)
        probe.wait_until(lambda: command.publish(turn) or red_share(images[-1]) > 0.05)
        turned = len(images)
    finally:
        supervisor.stop()
    assert red_share(images[ahead - 1]) == 0.0  # looking ahead: the red box is out of view
    assert turned > ahead
    first = images[0]
    assert (first.encoding, first.width, first.height, first.step) == ("rgb8", 320, 240, 960)
    assert first.header.frame_id == "CameraTop_optical_frame"
    stamps = [stamp_s(m.header.stamp) for m in images]
    assert stamps == sorted(stamps)
    assert len(set(stamps)) == len(stamps)
    info_stamps = {(m.header.stamp.sec, m.header.stamp.nanosec) for m in infos}
    image_stamps = {(m.header.stamp.sec, m.header.stamp.nanosec) for m in images}
    assert info_stamps & image_stamps  # each image has its camera info, stamped alike
    assert infos[0].k[2] == 160.0
    assert infos[0].k[5] == 120.0


def _spawned(pid: int) -> list[int]:
    """The processes ``pid`` started with multiprocessing's spawn (Linux: /proc)."""
    tasks = Path(f"/proc/{pid}/task")
    found: list[int] = []
    for task in tasks.iterdir() if tasks.is_dir() else []:
        children = task / "children"
        for child in children.read_text().split() if children.is_file() else []:
            command = Path(f"/proc/{child}/cmdline").read_bytes()
            if b"spawn_main" in command and b"resource_tracker" not in command:
                found.append(int(child))
    return found


def test_when_the_camera_process_is_killed_expect_it_reported_and_pictures_again(
    tmp_path: Path, probe: Probe
) -> None:
    import os
    import signal

    from diagnostic_msgs.msg import DiagnosticArray

    images: list[Image] = []
    warnings: list[str] = []
    probe.create_subscription(Image, absolute(CAMERA_IMAGE), images.append, qos_profile_sensor_data)

    def diagnostics(msg: DiagnosticArray) -> None:
        warnings.extend(s.message for s in msg.status if s.name.endswith("/pepper_sim_node"))

    probe.create_subscription(DiagnosticArray, "/diagnostics", diagnostics, 50)
    supervisor = NodeSupervisor(
        {"pepper_sim_node": executable_command("pepper_sim_node")}, tmp_path
    )
    supervisor.start()
    try:
        probe.wait_until(lambda: len(images) >= 2)
        sim = supervisor.processes["pepper_sim_node"].pid
        (camera,) = _spawned(sim)  # the head camera's process (no voice: no other)
        os.kill(camera, signal.SIGKILL)
        killed = len(images)
        probe.wait_until(lambda: any("head camera's process died" in m for m in warnings))
        probe.wait_until(lambda: len(images) >= killed + 3)
    finally:
        supervisor.stop()
    died = next(m for m in warnings if "head camera's process died" in m)
    assert "exit code -9" in died
    stamps = [stamp_s(m.header.stamp) for m in images]
    assert stamps == sorted(stamps)  # pictures again, after the restart, in order

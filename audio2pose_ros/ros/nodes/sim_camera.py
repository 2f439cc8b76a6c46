"""The simulated Pepper's head camera on naoqi_driver's topics.

``pepper_sim_node`` builds a :class:`SimCamera`: the picture
(:class:`~audio2pose_ros.robot.head_camera.HeadCamera`) is rendered in a process of its own, as
a robot's camera runs beside its motors, so the simulation's joint loop never waits for it. At
most ``camera_fps`` a second, and only while someone subscribes, the node sends the measured
pose and publishes what comes back:

- ``camera/front/image_raw`` (sensor_msgs/Image, rgb8, 320x240), stamped with the time of the
  pose it shows, frame ``CameraTop_optical_frame``, as naoqi_driver publishes the front camera;
- ``camera/front/camera_info`` (sensor_msgs/CameraInfo): the pinhole model with the same stamp.

One pose is in flight at a time: a slow render gives fewer frames, never a queue. A camera
process that dies (killed, out of memory) is reported on /diagnostics (WARN, with its exit code)
and started again, at most once every :data:`RESTART_PERIOD_S`.
"""

from __future__ import annotations

import multiprocessing
import time
from collections.abc import Callable

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image

from audio2pose_ros import topics
from audio2pose_ros.robot.head_camera import CameraModel, run_head_camera
from audio2pose_ros.ros.diagnosed_node import DiagnosedNode

FRAME_ID = "CameraTop_optical_frame"
RESTART_PERIOD_S = 5.0  # a camera process that died is started again at most this often (s)


class SimCamera:
    """The head camera of the simulated robot on ``node`` (see the module text).

    Args:
        node: the simulated robot's node.
        fps: frames a second at most (0: no camera, no process).
        pose: the measured pose now (joint name -> rad), called on the node's executor.
    """

    def __init__(
        self, node: DiagnosedNode, fps: float, pose: Callable[[], dict[str, float]]
    ) -> None:
        self.node = node
        self.model = CameraModel()
        self.pose = pose
        self.frames = 0
        self.refused = 0
        self.restarts = 0
        self.started_s = -RESTART_PERIOD_S  # when the camera's process was last started
        self.in_flight = False
        self.process: multiprocessing.process.BaseProcess | None = None
        if fps <= 0.0:
            return
        self.image_pub = node.create_publisher(Image, topics.CAMERA_IMAGE, qos_profile_sensor_data)
        self.info_pub = node.create_publisher(
            CameraInfo, topics.CAMERA_INFO, qos_profile_sensor_data
        )
        self.start()
        node.create_timer(1.0 / fps, node.guarded(self.on_tick))

    def start(self) -> None:
        """Start the camera's process (rendering) and connect to it."""
        context = multiprocessing.get_context("spawn")
        self.conn, child = context.Pipe()
        self.process = context.Process(
            target=run_head_camera,
            args=(self.model.width, self.model.height, child),
            name="head-camera",
            daemon=True,
        )
        self.process.start()
        self.started_s = time.monotonic()
        self.in_flight = False
        child.close()

    def on_tick(self) -> None:
        """Publish a rendered frame if one is back; ask for the next while someone watches."""
        if self.process is None:
            return
        if not self.process.is_alive():
            self.restart()
            return
        if self.in_flight and self.conn.poll():
            stamp_s, image = self.conn.recv()
            self.in_flight = False
            if image is None:
                self.refused += 1
            else:
                self.publish(stamp_s, image)
        if not self.in_flight and self.image_pub.get_subscription_count() > 0:
            now = self.node.get_clock().now().nanoseconds * 1e-9
            self.conn.send((now, self.pose()))
            self.in_flight = True

    def restart(self) -> None:
        """The camera's process died: report it, start another (at most every RESTART_PERIOD_S)."""
        if self.process is None:
            return
        code = self.process.exitcode
        self.node.report_problem(
            "camera process died",
            DiagnosticStatus.WARN,
            f"the head camera's process died (exit code {code}): no pictures; started again "
            f"({self.restarts} restarts so far)",
            hold_s=RESTART_PERIOD_S,
        )
        if time.monotonic() - self.started_s < RESTART_PERIOD_S:
            return
        self.conn.close()
        self.process.join(0.0)
        self.restarts += 1
        self.start()

    def publish(self, stamp_s: float, rgb: bytes) -> None:
        """The image and its camera info, as naoqi_driver publishes the front camera."""
        image = Image()
        image.header.stamp.sec = int(stamp_s)
        image.header.stamp.nanosec = int((stamp_s - int(stamp_s)) * 1e9)
        image.header.frame_id = FRAME_ID
        image.height, image.width = self.model.height, self.model.width
        image.encoding = "rgb8"
        image.step = 3 * self.model.width
        image.data = rgb
        info = CameraInfo()
        info.header = image.header
        info.height, info.width = image.height, image.width
        info.distortion_model = "plumb_bob"
        info.d = [0.0] * 5
        info.k = self.model.intrinsics()
        info.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
        f, cx, cy = info.k[0], info.k[2], info.k[5]
        info.p = [f, 0.0, cx, 0.0, 0.0, f, cy, 0.0, 0.0, 0.0, 1.0, 0.0]
        self.image_pub.publish(image)
        self.info_pub.publish(info)
        self.frames += 1

    def diagnostic_values(self) -> dict[str, object]:
        """Frames published, poses the camera refused, restarts of its process."""
        return {
            "camera_frames": self.frames,
            "camera_refused": self.refused,
            "camera_restarts": self.restarts,
        }

    def close(self) -> None:
        """End the camera's process."""
        if self.process is not None:
            self.conn.close()
            self.process.join(2.0)
            if self.process.is_alive():
                self.process.terminate()
            self.process = None

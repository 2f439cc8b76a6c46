"""The simulated Pepper's head camera: what CameraTop sees of a small room, rendered on the CPU.

:class:`HeadCamera` loads the package's URDF into a pybullet client of its own (visual only,
never stepped) with a room around the robot: a floor, a back wall, a person-like shape in front
of Pepper and coloured boxes to its left and right, so that turning the head changes the
picture. :meth:`HeadCamera.render` puts the joints at the given angles and renders from
CameraTop with pybullet's TinyRenderer (software, no display), as an ``(height, width, 3)`` rgb8
array, the image naoqi_driver publishes on ``camera/front/image_raw``.

CameraTop sits in the Head link's frame at (0.0868, 0, 0.1631) m, pitched down 0.0209 rad
(Aldebaran's Pepper 1.8 documentation, "Video camera"), and looks along the head's x axis; the
horizontal field of view is 55.2 degrees. The head's own sphere encloses that point, so the
near plane (:data:`NEAR_M`) lies beyond the head's surface in front of the lens.

:func:`run_head_camera` serves a camera in a process of its own (the simulated node starts it),
so rendering never holds up the simulation's joint loop.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np

from audio2pose_ros.errors import InputError
from audio2pose_ros.robot.kinematics import default_urdf_path
from audio2pose_ros.robot.quiet import quiet_c_output

CAMERA_LINK = "Head"
CAMERA_XYZ_M = (0.0868, 0.0, 0.1631)  # CameraTop in the Head link's frame (m)
CAMERA_PITCH_RAD = 0.0209  # CameraTop looks this much below the head's x axis
HORIZONTAL_FOV_DEG = 55.2
NEAR_M = 0.06  # beyond the head sphere's surface in front of the lens (0.017 m)
FAR_M = 8.0


@dataclass(frozen=True)
class CameraModel:
    """Size and pinhole intrinsics of the rendered image (pixels)."""

    width: int = 320
    height: int = 240

    def __post_init__(self) -> None:
        """Refuse sizes the renderer cannot make or a page cannot take."""
        if not (16 <= self.width <= 1280 and 16 <= self.height <= 960):
            raise InputError(f"camera size {self.width}x{self.height}: 16x16 to 1280x960")

    @property
    def focal_px(self) -> float:
        """Focal length in pixels (square pixels) for :data:`HORIZONTAL_FOV_DEG`."""
        return self.width / 2.0 / math.tan(math.radians(HORIZONTAL_FOV_DEG) / 2.0)

    @property
    def vertical_fov_deg(self) -> float:
        """The vertical field of view that the focal length gives."""
        return math.degrees(2.0 * math.atan(self.height / 2.0 / self.focal_px))

    def intrinsics(self) -> list[float]:
        """The row-major 3x3 matrix K of sensor_msgs/CameraInfo."""
        f = self.focal_px
        return [f, 0.0, self.width / 2.0, 0.0, f, self.height / 2.0, 0.0, 0.0, 1.0]


# (half extents (m), position (m), rgba): the room the camera sees, Pepper at the origin facing +x
ROOM_BOXES = (
    ((4.0, 4.0, 0.01), (0.0, 0.0, -0.01), (0.55, 0.5, 0.45, 1.0)),  # floor
    ((0.05, 4.0, 1.5), (3.5, 0.0, 1.5), (0.85, 0.85, 0.8, 1.0)),  # back wall
    ((0.25, 0.25, 0.35), (1.6, 1.4, 0.35), (0.9, 0.15, 0.1, 1.0)),  # red box, Pepper's left
    ((0.25, 0.25, 0.35), (1.6, -1.4, 0.35), (0.1, 0.3, 0.9, 1.0)),  # blue box, Pepper's right
    ((0.2, 0.2, 0.2), (2.4, 0.0, 1.9), (0.95, 0.8, 0.1, 1.0)),  # yellow box above the person
)
PERSON_AT_M = (2.2, 0.0)  # a person-like shape in front of Pepper: body, head
PERSON_RGBA = (0.2, 0.6, 0.3, 1.0)
SKIN_RGBA = (0.9, 0.7, 0.55, 1.0)


class HeadCamera:
    """Pepper's CameraTop in a small room (see the module text).

    Args:
        camera: image size.
        urdf_path: the robot model (the package's by default).
    """

    def __init__(self, camera: CameraModel | None = None, urdf_path: Path | None = None) -> None:
        import pybullet

        self.camera = camera or CameraModel()
        self._p: Any = pybullet
        self._client = pybullet.connect(pybullet.DIRECT)
        c = self._client
        with quiet_c_output():  # the URDF importer warns of links without inertia
            self._body = pybullet.loadURDF(
                str(urdf_path or default_urdf_path()), useFixedBase=True, physicsClientId=c
            )
        self._joints: dict[str, int] = {}
        self._link = -1
        for i in range(pybullet.getNumJoints(self._body, physicsClientId=c)):
            info = pybullet.getJointInfo(self._body, i, physicsClientId=c)
            self._joints[info[1].decode()] = i
            if info[12].decode() == CAMERA_LINK:
                self._link = i
        if self._link < 0:
            raise InputError(f"the robot model has no {CAMERA_LINK} link for the camera")
        for half, position, rgba in ROOM_BOXES:
            self._add(pybullet.GEOM_BOX, position, rgba, halfExtents=half)
        x, y = PERSON_AT_M
        self._add(pybullet.GEOM_CYLINDER, (x, y, 0.75), PERSON_RGBA, radius=0.2, length=1.5)
        self._add(pybullet.GEOM_SPHERE, (x, y, 1.65), SKIN_RGBA, radius=0.14)
        self.frames = 0
        aspect = self.camera.width / self.camera.height
        self._projection = pybullet.computeProjectionMatrixFOV(
            self.camera.vertical_fov_deg, aspect, NEAR_M, FAR_M, physicsClientId=c
        )

    def _add(
        self, shape: int, position: tuple[float, ...], rgba: tuple[float, ...], **size: Any
    ) -> None:
        visual = self._p.createVisualShape(
            shape, rgbaColor=list(rgba), physicsClientId=self._client, **size
        )
        self._p.createMultiBody(
            baseMass=0.0,
            baseVisualShapeIndex=visual,
            basePosition=list(position),
            physicsClientId=self._client,
        )

    def close(self) -> None:
        """Disconnect from pybullet."""
        if self._client >= 0:
            self._p.disconnect(physicsClientId=self._client)
            self._client = -1

    def render(self, pose_rad: Mapping[str, float]) -> np.ndarray:
        """The picture at ``pose_rad`` (joint name -> angle; others stay where they were).

        Returns:
            ``(height, width, 3)`` uint8 RGB, row 0 at the top.

        Raises:
            InputError: a joint the model does not have, or an angle that is not finite.
        """
        p, c = self._p, self._client
        for name, angle in pose_rad.items():
            if name not in self._joints:
                raise InputError(f"unknown joint {name!r}")
            if not math.isfinite(angle):
                raise InputError(f"joint {name}: angle {angle!r} is not finite")
            p.resetJointState(self._body, self._joints[name], float(angle), physicsClientId=c)
        state = p.getLinkState(self._body, self._link, computeForwardKinematics=True,
                               physicsClientId=c)  # fmt: skip
        position, orientation = np.array(state[4]), state[5]
        rotation = np.array(p.getMatrixFromQuaternion(orientation)).reshape(3, 3)
        eye = position + rotation @ np.array(CAMERA_XYZ_M)
        pitch = CAMERA_PITCH_RAD
        forward = rotation @ np.array([math.cos(pitch), 0.0, -math.sin(pitch)])
        up = rotation @ np.array([math.sin(pitch), 0.0, math.cos(pitch)])
        view = p.computeViewMatrix(list(eye), list(eye + forward), list(up), physicsClientId=c)
        _, _, rgba, _, _ = p.getCameraImage(
            self.camera.width,
            self.camera.height,
            viewMatrix=view,
            projectionMatrix=self._projection,
            renderer=p.ER_TINY_RENDERER,
            flags=p.ER_NO_SEGMENTATION_MASK,
            physicsClientId=c,
        )
        image = np.asarray(rgba, dtype=np.uint8).reshape(self.camera.height, self.camera.width, 4)
        self.frames += 1
        return np.ascontiguousarray(image[:, :, :3])


def run_head_camera(width: int, height: int, conn: Connection) -> None:
    """Serve a :class:`HeadCamera` over ``conn`` until it closes (a process's target).

    Each ``(stamp_s, pose)`` received is answered with ``(stamp_s, rgb bytes)``; poses that
    arrive while one renders are skipped but the newest, so a slow render makes fewer frames,
    never a backlog. A refused pose is answered with ``(stamp_s, None)``.
    """
    camera = HeadCamera(CameraModel(width, height))
    try:
        while True:
            try:
                request = conn.recv()
                while conn.poll():
                    request = conn.recv()
            except (EOFError, OSError):
                return
            stamp_s, pose = request
            try:
                image: bytes | None = camera.render(pose).tobytes()
            except InputError:
                image = None
            try:
                conn.send((stamp_s, image))
            except (BrokenPipeError, OSError):
                return
    finally:
        camera.close()

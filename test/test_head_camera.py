"""The simulated Pepper's head camera: a room seen from CameraTop, following the head."""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
import pytest

from audio2pose_ros.errors import InputError
from audio2pose_ros.robot.head_camera import CameraModel, HeadCamera


@pytest.fixture(scope="module")
def camera() -> Iterator[HeadCamera]:
    cam = HeadCamera(CameraModel(160, 120))
    yield cam
    cam.close()


def test_when_rendered_expect_rgb8_image_of_the_room(camera: HeadCamera) -> None:
    image = camera.render({"HeadYaw": 0.0, "HeadPitch": 0.0})
    assert image.shape == (120, 160, 3)
    assert image.dtype == np.uint8
    # the person-like shape in front (green body) is in the middle of the picture
    middle = image[40:80, 70:90].reshape(-1, 3).astype(int)
    assert (middle[:, 1] > middle[:, 0] + 40).mean() > 0.5


def test_when_the_head_turns_left_expect_the_red_box_in_view(camera: HeadCamera) -> None:
    ahead = camera.render({"HeadYaw": 0.0, "HeadPitch": 0.0})
    left = camera.render({"HeadYaw": 1.0, "HeadPitch": 0.0})
    right = camera.render({"HeadYaw": -1.0, "HeadPitch": 0.0})

    def red(image: np.ndarray) -> float:
        rgb = image.reshape(-1, 3).astype(int)
        return float(((rgb[:, 0] > 150) & (rgb[:, 1] < 80) & (rgb[:, 2] < 80)).mean())

    def blue(image: np.ndarray) -> float:
        rgb = image.reshape(-1, 3).astype(int)
        return float(((rgb[:, 2] > 150) & (rgb[:, 0] < 80)).mean())

    assert red(ahead) == 0.0
    assert blue(ahead) == 0.0
    assert red(left) > 0.05
    assert blue(left) == 0.0
    assert blue(right) > 0.05
    assert red(right) == 0.0


def test_when_the_head_pitches_expect_the_picture_to_change(camera: HeadCamera) -> None:
    up = camera.render({"HeadYaw": 0.0, "HeadPitch": -0.6})
    down = camera.render({"HeadYaw": 0.0, "HeadPitch": 0.4})
    assert np.abs(up.astype(int) - down.astype(int)).mean() > 10.0


def test_when_a_pose_is_bad_expect_input_error(camera: HeadCamera) -> None:
    with pytest.raises(InputError, match="unknown joint"):
        camera.render({"Antenna": 0.0})
    with pytest.raises(InputError, match="not finite"):
        camera.render({"HeadYaw": math.nan})


def test_when_the_size_is_out_of_range_expect_input_error() -> None:
    with pytest.raises(InputError, match="camera size"):
        CameraModel(4, 4)


def test_when_camera_info_is_made_expect_the_field_of_view_in_k() -> None:
    model = CameraModel(320, 240)
    k = model.intrinsics()
    assert k[2] == 160.0
    assert k[5] == 120.0
    assert math.degrees(2 * math.atan(160.0 / k[0])) == pytest.approx(55.2)

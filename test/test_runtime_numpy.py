"""Torch-free streaming inference: numpy kernels against torch on real speech.

Tolerance: poses are in [0, 1] (normalised joint ranges); the kernels compute in float64 from
the float32 weights, torch's ``forward`` in float32, so they agree to 1e-5 (about 1e-5 rad on
Pepper's widest joint range). Against the models' own numpy streaming predictors (float64 too)
they agree to 1e-12.
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.numpy import load_file, save_file

from audio2pose_ros.audio.features import FeatureSpec, extract_features
from audio2pose_ros.audio.normalize import FeatureNormalizer
from audio2pose_ros.checkpoints.format import (
    DIGEST_KEY,
    HEADER_KEY,
    CheckpointError,
    digest_update,
    read_checkpoint_file,
)
from audio2pose_ros.checkpoints.numpy_runtime import load_streaming_model
from audio2pose_ros.checkpoints.torch_io import Checkpoint, load_checkpoint, save_checkpoint
from audio2pose_ros.models.base import OfflineOnlyModelError
from audio2pose_ros.models.registry import build_model
from audio2pose_ros.models.warm_start import WARM_START_FRAMES, with_warm_start
from audio2pose_ros.resources import default_checkpoint_path
from audio2pose_ros.robot.description import RobotDescription


def _stepped_after_quiet_warm_up(reference, frames: np.ndarray) -> np.ndarray:
    """A sampler's poses frame by frame after its warm-up, which it samples at temperature 0."""
    temperature = reference.temperature
    reference.temperature = 0.0
    for frame in with_warm_start(frames[:1])[:WARM_START_FRAMES]:
        reference.step(frame)
    reference.temperature = temperature
    return np.array([reference.step(f) for f in frames])


TORCH_TOLERANCE = 1e-5  # [0, 1] pose units: float64 kernels vs torch float32 forward
PREDICTOR_TOLERANCE = 1e-12  # vs the models' own float64 numpy predictors


@pytest.fixture(scope="module")
def speech_features(speech: np.ndarray) -> tuple[np.ndarray, FeatureNormalizer]:
    """Raw LogFB-26 frames of the bundled speech and a normaliser fitted on them."""
    raw = extract_features(speech, FeatureSpec())
    return raw, FeatureNormalizer.fit(raw)


def _checkpoint(
    tmp_path: Path,
    name: str,
    robot: RobotDescription,
    normalizer: FeatureNormalizer,
    config: dict | None = None,
) -> Path:
    torch.manual_seed(3)
    model = build_model(name, {"n_features": 26, "n_joints": robot.n_joints, **(config or {})})
    with torch.no_grad():  # untrained biases are small: widen them so outputs vary
        for tensor in model.state_dict().values():
            tensor.add_(0.3 * torch.randn_like(tensor))
    return save_checkpoint(
        tmp_path / f"{name}.safetensors",
        Checkpoint(model.eval(), FeatureSpec(), normalizer, robot),
    )


@pytest.mark.parametrize(
    ("name", "config"),
    [
        ("mlp", {}),
        ("mlp", {"dropout": 0.2, "hidden_layers": 2}),
        ("lstm", {}),
        ("live", {}),
        ("live", {"noise_order": 2}),
        ("live", {"noise_order": 2, "noise_burst": 0.8}),
        ("live_groups", {}),
        ("live_groups", {"first_burst": 0.6, "second_burst": 1.2}),
        ("live_groups", {"first_burst": [0.0, 1.2]}),  # per joint, as a checkpoint's JSON holds it
    ],
)
def test_when_a_streaming_model_runs_on_real_speech_expect_numpy_kernel_equals_torch(
    tmp_path: Path,
    robot: RobotDescription,
    speech_features: tuple[np.ndarray, FeatureNormalizer],
    name: str,
    config: dict,
) -> None:
    raw, normalizer = speech_features
    path = _checkpoint(tmp_path, name, robot, normalizer, config)
    loaded = load_streaming_model(path, robot=robot)
    assert loaded.runtime == "numpy"
    torch_model = load_checkpoint(path, robot=robot).model
    frames = loaded.normalizer.apply(raw)
    options = {"temperature": 0.0} if name.startswith("live") else {}
    numpy_poses = loaded.predictor(**options).run(frames)
    with torch.no_grad():  # both start settled: the warm-up frames' poses are dropped
        warmed = torch.from_numpy(with_warm_start(frames)).float()[None]
        torch_poses = torch_model(warmed)[0].double().numpy()[WARM_START_FRAMES:]
    assert numpy_poses.shape == (len(raw), robot.n_joints)
    assert np.ptp(numpy_poses, axis=0).max() > 0.05  # the comparison is not between constants
    np.testing.assert_allclose(numpy_poses, torch_poses, atol=TORCH_TOLERANCE, rtol=0)


@pytest.mark.parametrize(
    ("name", "config"),
    [
        ("live", {}),
        ("live", {"noise_order": 2}),
        ("live", {"noise_burst": 1.0}),
        ("live_groups", {}),
        ("live_groups", {"first_burst": 1.2, "second_burst": 0.6}),
        ("live_groups", {"first_burst": [1.2, 0.0], "second_burst": 0.6}),  # one per head joint
        ("live_groups", {"noise_order": 2, "first_correlation": 0.9, "second_correlation": 0.99}),
        ("live_groups", {"body_margin_m": 0.0, "body_band_m": 0.5}),  # body-aware: every frame
        ("live_groups", {"second_temperature": [3.0] * 8 + [0.5]}),  # the hip colder
        # hot enough that the velocity limit bounds many steps
        (
            "live_groups",
            {"first_temperature": 40.0, "second_temperature": 40.0, "velocity_limit": 1},
        ),
    ],
)
def test_when_a_live_model_samples_expect_the_same_poses_as_its_torch_side_predictor(
    tmp_path: Path,
    robot: RobotDescription,
    speech_features: tuple[np.ndarray, FeatureNormalizer],
    name: str,
    config: dict,
) -> None:
    raw, normalizer = speech_features
    path = _checkpoint(tmp_path, name, robot, normalizer, config)
    frames = normalizer.apply(raw)
    kernel = load_streaming_model(path, robot=robot).predictor(seed=5, temperature=1.0)
    reference = load_checkpoint(path, robot=robot).model.streaming_predictor(seed=5)
    sampled = kernel.run(frames)
    expected = _stepped_after_quiet_warm_up(reference, frames)
    np.testing.assert_allclose(sampled, expected, atol=PREDICTOR_TOLERANCE, rtol=0)
    kernel.reset()
    np.testing.assert_allclose(kernel.run(frames[:50]), expected[:50], atol=PREDICTOR_TOLERANCE)


def test_when_the_packaged_model_runs_on_real_speech_expect_torch_poses(
    robot: RobotDescription, speech_features: tuple[np.ndarray, FeatureNormalizer]
) -> None:
    raw, _ = speech_features
    loaded = load_streaming_model(default_checkpoint_path(), robot=robot)
    checkpoint = load_checkpoint(default_checkpoint_path(), robot=robot)
    assert loaded.runtime == "numpy"
    frames = loaded.normalizer.apply(raw)
    predictor = loaded.predictor()
    stepped = np.array([predictor.step(f) for f in frames])
    expected = _stepped_after_quiet_warm_up(checkpoint.model.streaming_predictor(), frames)
    np.testing.assert_allclose(stepped, expected, atol=TORCH_TOLERANCE, rtol=0)


def test_when_the_packaged_model_is_loaded_for_streaming_expect_torch_not_imported() -> None:
    script = (
        "import sys\n"
        "from audio2pose_ros.checkpoints.numpy_runtime import load_streaming_model\n"
        "from audio2pose_ros.resources import default_checkpoint_path\n"
        "model = load_streaming_model(default_checkpoint_path())\n"
        "model.predictor().step([0.0] * 26)\n"
        "print(model.runtime, 'torch' in sys.modules)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, check=True, timeout=60
    )
    assert out.stdout.split() == ["numpy", "False"]


def _write_raw_checkpoint(
    path: Path, source: Path, tensors: dict[str, np.ndarray], header_edit: dict | None = None
) -> Path:
    """``source``'s header with ``tensors`` (and header changes), with a valid digest."""
    header = json.loads(read_checkpoint_file(source).header_text)
    header.update(header_edit or {})
    header_text = json.dumps(header, sort_keys=True)
    sha = hashlib.sha256(header_text.encode("utf-8"))
    for name in sorted(tensors):
        digest_update(sha, name, tensors[name].shape, np.ascontiguousarray(tensors[name]).tobytes())
    save_file(tensors, str(path), metadata={HEADER_KEY: header_text, DIGEST_KEY: sha.hexdigest()})
    return path


@pytest.fixture
def mlp_path(
    tmp_path: Path, robot: RobotDescription, speech_features: tuple[np.ndarray, FeatureNormalizer]
) -> Path:
    """An MLP checkpoint (the hostile variants below edit its tensors)."""
    return _checkpoint(tmp_path, "mlp", robot, speech_features[1])


def _tensors(path: Path) -> dict[str, np.ndarray]:
    return load_file(str(path))


def test_when_a_tensor_has_another_shape_than_the_config_expect_refusal(
    tmp_path: Path, mlp_path: Path
) -> None:
    source = mlp_path
    tensors = _tensors(source)
    tensors["net.0.weight"] = np.zeros((8, 25), dtype=np.float32)
    bad = _write_raw_checkpoint(tmp_path / "shape.safetensors", source, tensors)
    with pytest.raises(CheckpointError, match=r"'net.0.weight' has shape \[8, 25\]"):
        load_streaming_model(bad)


def test_when_a_tensor_is_missing_or_extra_expect_refusal(tmp_path: Path, mlp_path: Path) -> None:
    source = mlp_path
    tensors = _tensors(source)
    tensors["net.99.weight"] = tensors.pop("net.14.weight")
    bad = _write_raw_checkpoint(tmp_path / "names.safetensors", source, tensors)
    with pytest.raises(CheckpointError, match=r"missing.*net\.14\.weight.*unexpected.*net\.99"):
        load_streaming_model(bad)


def test_when_a_weight_is_not_finite_expect_refusal(tmp_path: Path, mlp_path: Path) -> None:
    source = mlp_path
    tensors = _tensors(source)
    tensors["net.2.bias"][3] = np.nan
    bad = _write_raw_checkpoint(tmp_path / "nan.safetensors", source, tensors)
    with pytest.raises(CheckpointError, match=r"'net\.2\.bias' is not finite float32"):
        load_streaming_model(bad)


def test_when_a_tensor_is_float64_expect_refusal_not_a_cast(tmp_path: Path, mlp_path: Path) -> None:
    source = mlp_path
    tensors = _tensors(source)
    tensors["net.0.bias"] = tensors["net.0.bias"].astype(np.float64)
    bad = _write_raw_checkpoint(tmp_path / "f64.safetensors", source, tensors)
    with pytest.raises(CheckpointError, match="dtype 'F64'"):
        load_streaming_model(bad)


def test_when_the_header_is_edited_after_saving_expect_digest_refusal(
    tmp_path: Path, mlp_path: Path
) -> None:
    data = bytearray(mlp_path.read_bytes())
    at = data.index(b"hidden_units")
    data[at : at + 12] = b"hidden_Units"
    (tmp_path / "edited.safetensors").write_bytes(bytes(data))
    with pytest.raises(CheckpointError, match="checksum mismatch"):
        load_streaming_model(tmp_path / "edited.safetensors")


def test_when_the_robot_differs_expect_refusal(robot: RobotDescription) -> None:
    other = robot.to_dict()
    other["joints"][0]["max_rad"] -= 0.1
    with pytest.raises(CheckpointError, match="made for other joints"):
        load_streaming_model(default_checkpoint_path(), robot=RobotDescription.from_dict(other))


def test_when_a_model_has_no_numpy_kernel_expect_torch_loader_or_refusal(
    tmp_path: Path, robot: RobotDescription, speech_features: tuple[np.ndarray, FeatureNormalizer]
) -> None:
    path = _checkpoint(tmp_path, "blstm", robot, speech_features[1])
    with pytest.raises(OfflineOnlyModelError, match="cannot run online"):
        load_streaming_model(path, robot=robot)
    with pytest.raises(CheckpointError, match="no numpy kernel"):
        load_streaming_model(path, robot=robot, allow_torch=False)


def test_when_the_packaged_sampler_runs_slices_expect_the_poses_of_stepping_frame_by_frame(
    robot: RobotDescription, speech_features: tuple[np.ndarray, FeatureNormalizer]
) -> None:
    """The node runs a message's frames a few at a time: the same poses as one by one, and a
    caller that writes into the poses it got does not change the next frame's."""
    loaded = load_streaming_model(default_checkpoint_path(), robot=robot)
    frames = loaded.normalizer.apply(speech_features[0][:300])
    stepper, runner = loaded.predictor(seed=0).predictor, loaded.predictor(seed=0).predictor
    expected = np.array([stepper.step(f) for f in frames])
    got = []
    for begin in range(0, len(frames), 7):
        poses = runner.run(frames[begin : begin + 7])
        got.append(poses.copy())
        poses[:] = 0.0  # the caller's to change
    assert np.array_equal(np.concatenate(got), expected)

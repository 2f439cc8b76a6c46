"""Checkpoints: self-describing, code-free, refused with a clear message when they do not fit."""

import json
import struct

import numpy as np
import pytest
import torch

from audio2pose_ros.audio.features import FeatureSpec
from audio2pose_ros.audio.normalize import FeatureNormalizer
from audio2pose_ros.checkpoints.format import CheckpointError, feature_spec_of
from audio2pose_ros.checkpoints.torch_io import Checkpoint, load_checkpoint, save_checkpoint
from audio2pose_ros.models.mlp import FramewiseMLP, MLPConfig
from audio2pose_ros.resources import default_checkpoint_path
from audio2pose_ros.robot.description import RobotDescription


@pytest.fixture
def saved(tmp_path, robot):
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    checkpoint = Checkpoint(
        model=FramewiseMLP(MLPConfig()).eval(),
        features=FeatureSpec(),
        normalizer=FeatureNormalizer.fit(rng.normal(size=(100, 26))),
        robot=robot,
        info={"note": "test"},
    )
    return save_checkpoint(tmp_path / "m.safetensors", checkpoint), checkpoint


def test_when_saved_and_loaded_expect_same_model_spec_normalizer_and_robot(saved, robot):
    path, original = saved
    loaded = load_checkpoint(path, robot=robot, features=FeatureSpec())
    x = torch.randn(3, 26)
    torch.testing.assert_close(loaded.model(x), original.model(x))
    assert loaded.features == original.features
    np.testing.assert_allclose(loaded.normalizer.mean, original.normalizer.mean)
    assert loaded.robot.names == robot.names
    assert loaded.info == {"note": "test"}
    assert feature_spec_of(path) == FeatureSpec()


def test_when_tensor_bytes_tampered_expect_checksum_error(saved):
    path, _ = saved
    data = bytearray(path.read_bytes())
    data[-3] ^= 0xFF  # flip bits inside the last tensor
    path.write_bytes(bytes(data))
    with pytest.raises(CheckpointError, match="checksum mismatch, the file was modified"):
        load_checkpoint(path)


def test_when_header_edited_expect_checksum_error(saved):
    path, _ = saved
    raw = path.read_bytes()
    size = struct.unpack("<Q", raw[:8])[0]
    header = json.loads(raw[8 : 8 + size])
    meta = json.loads(header["__metadata__"]["audio2pose"])
    meta["robot"]["joints"][0]["max_rad"] = 2.0  # pretend HeadPitch may go further
    header["__metadata__"]["audio2pose"] = json.dumps(meta, sort_keys=True)
    new_header = json.dumps(header).encode()
    new_header += b" " * (-len(new_header) % 8)
    path.write_bytes(struct.pack("<Q", len(new_header)) + new_header + raw[8 + size :])
    with pytest.raises(CheckpointError, match="checksum mismatch"):
        load_checkpoint(path)


def test_when_robot_joints_differ_expect_error_listing_difference(saved, robot):
    path, _ = saved
    data = robot.to_dict()
    data["joints"][10]["min_rad"] = -0.3
    other = RobotDescription.from_dict(data)
    with pytest.raises(
        CheckpointError, match=r"HipRoll range \[-0.5149, 0.5149\] != \[-0.3, 0.5149\]"
    ):
        load_checkpoint(path, robot=other)
    reordered = RobotDescription(name="pepper", joints=tuple(reversed(robot.joints)))
    with pytest.raises(CheckpointError, match="joint order"):
        load_checkpoint(path, robot=reordered)


def test_when_features_differ_expect_error_naming_field(saved):
    path, _ = saved
    with pytest.raises(CheckpointError, match=r"made for other audio features: .*nfilt"):
        load_checkpoint(path, features=FeatureSpec(nfilt=40))


def test_when_not_a_checkpoint_expect_clear_error(tmp_path):
    junk = tmp_path / "junk.safetensors"
    junk.write_bytes(b"\x00" * 64)
    with pytest.raises(CheckpointError, match="not an audio2pose checkpoint"):
        load_checkpoint(junk)
    with pytest.raises(CheckpointError, match="checkpoint file not found"):
        load_checkpoint(tmp_path / "missing.safetensors")


def test_when_loading_packaged_default_expect_it_matches_the_robot(robot):
    checkpoint = load_checkpoint(default_checkpoint_path(), robot=robot)
    assert checkpoint.model.streaming
    assert "lecturer" in checkpoint.info["trained_on"]  # arms learned from a person, not a rule


@pytest.mark.parametrize("name", ["lstm", "dae_gru", "blstm", "blstm_prior", "cvae", "live"])
def test_when_any_model_saved_and_loaded_expect_same_output(name, tmp_path, robot):
    from audio2pose_ros.models.registry import build_model

    torch.manual_seed(0)
    model = build_model(name, {}).eval()
    checkpoint = Checkpoint(
        model=model,
        features=FeatureSpec(),
        normalizer=FeatureNormalizer.fit(np.random.default_rng(0).normal(size=(50, 26))),
        robot=robot,
    )
    path = save_checkpoint(tmp_path / f"{name}.safetensors", checkpoint)
    loaded = load_checkpoint(path, robot=robot)
    x = torch.randn(1, 40, 26)
    with torch.no_grad():
        torch.testing.assert_close(loaded.model(x), model(x))
    assert loaded.model.streaming == model.streaming

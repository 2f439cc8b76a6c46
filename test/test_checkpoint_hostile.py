"""Crafted checkpoints: every one is refused with one CheckpointError line, never a crash.

Each file here is what an attacker or a broken copy could hand to ``model_path``: the loader
(``load_checkpoint``) and the features node's reader (``feature_spec_of``) must both refuse it
with a message naming the file and the problem, in bounded memory and without recursion.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
import torch

from audio2pose_ros.audio.features import FeatureSpec
from audio2pose_ros.audio.normalize import FeatureNormalizer
from audio2pose_ros.checkpoints.format import (
    MAX_HEADER_BYTES,
    CheckpointError,
    feature_spec_of,
    json_depth,
)
from audio2pose_ros.checkpoints.torch_io import (
    Checkpoint,
    _digest,
    load_checkpoint,
    save_checkpoint,
)
from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.models.mlp import FramewiseMLP, MLPConfig

LOADERS = [load_checkpoint, feature_spec_of]


@pytest.fixture
def saved(tmp_path: Path, robot) -> Path:
    torch.manual_seed(0)
    checkpoint = Checkpoint(
        model=FramewiseMLP(MLPConfig()).eval(),
        features=FeatureSpec(),
        normalizer=FeatureNormalizer.fit(np.random.default_rng(0).normal(size=(100, 26))),
        robot=robot,
    )
    return save_checkpoint(tmp_path / "m.safetensors", checkpoint)


def split(path: Path) -> tuple[dict, bytes]:
    """The safetensors JSON header and the tensor bytes of a file."""
    raw = path.read_bytes()
    size = struct.unpack("<Q", raw[:8])[0]
    return json.loads(raw[8 : 8 + size]), raw[8 + size :]


def write(path: Path, container: dict | bytes, data: bytes) -> Path:
    text = container if isinstance(container, bytes) else json.dumps(container).encode()
    path.write_bytes(struct.pack("<Q", len(text)) + text + data)
    return path


def resealed(path: Path, edit_header) -> Path:
    """Edit the audio2pose header and store a matching digest, as a crafted file would."""
    container, data = split(path)
    header = json.loads(container["__metadata__"]["audio2pose"])
    edit_header(header)
    text = json.dumps(header, sort_keys=True)
    tensors = load_tensors(container, data)
    container["__metadata__"] = {"audio2pose": text, "audio2pose_sha256": _digest(text, tensors)}
    return write(path, container, data)


def load_tensors(container: dict, data: bytes) -> dict[str, torch.Tensor]:
    tensors = {}
    for name, entry in container.items():
        if name != "__metadata__":
            begin, end = entry["data_offsets"]
            array = np.frombuffer(data[begin:end], dtype=np.float32).reshape(entry["shape"])
            tensors[name] = torch.from_numpy(array.copy())
    return tensors


@pytest.mark.parametrize("load", LOADERS)
def test_when_header_is_a_list_expect_checkpoint_error_not_attribute_error(saved, load):
    container, data = split(saved)
    container["__metadata__"]["audio2pose"] = "[1, 2, 3]"
    write(saved, container, data)
    with pytest.raises(CheckpointError, match="audio2pose header must be a JSON object"):
        load(saved)
    write(saved, b"[1, 2, 3]", b"")
    with pytest.raises(CheckpointError, match=r"not an audio2pose checkpoint \(header is not an"):
        load(saved)


@pytest.mark.parametrize("load", LOADERS)
def test_when_header_nests_10000_levels_expect_depth_refused_not_recursion_error(tmp_path, load):
    path = write(tmp_path / "deep.safetensors", b"[" * 10_000 + b"]" * 10_000, b"")
    with pytest.raises(CheckpointError, match="nests 10000 levels deep, at most 32"):
        load(path)


@pytest.mark.parametrize("load", LOADERS)
def test_when_inner_header_nests_deeply_expect_depth_refused(saved, load):
    container, data = split(saved)
    container["__metadata__"]["audio2pose"] = "[" * 10_000 + "]" * 10_000
    write(saved, container, data)
    with pytest.raises(CheckpointError, match="audio2pose header nests 10000 levels"):
        load(saved)


@pytest.mark.parametrize("claimed", [2**63, MAX_HEADER_BYTES + 1, 10_000])
@pytest.mark.parametrize("load", LOADERS)
def test_when_header_length_is_huge_expect_refused_before_reading(tmp_path, load, claimed):
    path = tmp_path / "huge.safetensors"
    path.write_bytes(struct.pack("<Q", claimed) + b"{}")
    with pytest.raises(CheckpointError, match=f"header length {claimed} for a file of 10 bytes"):
        load(path)


@pytest.mark.parametrize("load", LOADERS)
def test_when_a_member_has_the_wrong_type_expect_named_in_the_error(saved, load):
    container, data = split(saved)
    container["__metadata__"]["audio2pose"] = json.dumps(
        {"format_version": 1, "model": [], "features": {}, "normalizer": {}, "robot": {}}
    )
    write(saved, container, data)
    with pytest.raises(CheckpointError, match="header section 'model' must be a JSON object"):
        load(saved)


def test_when_weights_are_int64_expect_refused_not_cast(saved):
    container, data = split(saved)
    tensors = load_tensors(container, data)
    tensors["net.0.bias"] = tensors["net.0.bias"].to(torch.int64)
    from safetensors.torch import save_file

    text = container["__metadata__"]["audio2pose"]
    save_file(
        tensors,
        str(saved),
        metadata={"audio2pose": text, "audio2pose_sha256": _digest(text, tensors)},
    )
    with pytest.raises(CheckpointError, match=r"tensor 'net\.0\.bias' has dtype 'I64'"):
        load_checkpoint(saved)


def test_when_features_header_edited_expect_feature_spec_of_refuses_it(saved):
    container, data = split(saved)
    header = json.loads(container["__metadata__"]["audio2pose"])
    header["features"]["nfilt"] = 40
    container["__metadata__"]["audio2pose"] = json.dumps(header, sort_keys=True)
    write(saved, container, data)
    with pytest.raises(CheckpointError, match="checksum mismatch"):
        feature_spec_of(saved)


def test_when_model_config_asks_for_a_billion_units_expect_refused_without_allocating(saved):
    resealed(saved, lambda h: h["model"]["config"].update(hidden_units=10**9))
    with pytest.raises(CheckpointError, match=r"hidden_units=1000000000 is outside \[0, 1024\]"):
        load_checkpoint(saved)


def test_when_tensor_shapes_do_not_fit_the_config_expect_refused(saved):
    resealed(saved, lambda h: h["model"]["config"].update(hidden_units=16))
    with pytest.raises(
        CheckpointError, match=r"'net\.0\.weight' has shape \[8, 26\], model 'mlp' needs \[16, 26\]"
    ):
        load_checkpoint(saved)


def test_when_normalizer_does_not_fit_the_features_expect_refused(saved):
    resealed(saved, lambda h: h["normalizer"].update(mean=[0.0] * 3, std=[1.0] * 3))
    with pytest.raises(
        CheckpointError, match="normalizer has 3 means and deviations, the features"
    ):
        load_checkpoint(saved)


@pytest.mark.parametrize("load", LOADERS)
def test_when_path_is_a_directory_or_empty_expect_one_line(tmp_path, load):
    with pytest.raises(CheckpointError, match="is a directory"):
        load(tmp_path)
    empty = tmp_path / "empty.safetensors"
    empty.write_bytes(b"")
    with pytest.raises(CheckpointError, match="header length 0 for a file of 0 bytes"):
        load(empty)


def test_when_checkpoint_is_refused_expect_a_configuration_error_for_nodes(tmp_path):
    with pytest.raises(ConfigurationError):
        load_checkpoint(tmp_path / "missing.safetensors")


def test_when_brackets_sit_inside_strings_expect_them_not_counted():
    assert json_depth('{"a": "[[[[{{{{", "b": [[1]]}') == 3
    assert json_depth('"\\"[[["') == 0


@pytest.mark.parametrize("load", LOADERS)
def test_when_the_path_is_a_device_or_fifo_expect_refused_without_reading(tmp_path, load):
    import os

    fifo = tmp_path / "model.fifo"
    os.mkfifo(fifo)  # opening it for reading would block until a writer comes
    for path in (fifo, Path("/dev/zero")):
        with pytest.raises(CheckpointError, match="not a regular file, expected a checkpoint"):
            load(path)

"""Hostile bag folders are refused within seconds and in bounded memory, naming the file."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from audio2pose_ros.data import bag as bag_module
from audio2pose_ros.data.bag import BagError, read_bag_audio, write_audio_bag

BOMB = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"{c}: &{c} [*{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}]\n"
    for p, c in zip("abcdefgh", "bcdefghi", strict=True)
)


def speech_bag(tmp_path: Path, speech) -> Path:
    out = tmp_path / "bag"
    write_audio_bag(speech[:16000], out)
    return out


def read_in_a_bounded_process(bag: Path) -> subprocess.CompletedProcess[str]:
    """Read the bag's audio in a child with 1 GiB of address space and a 60 s limit."""
    code = textwrap.dedent(
        f"""
        import resource, sys
        resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))
        from audio2pose_ros.data.bag import BagError, read_bag_audio
        try:
            read_bag_audio({str(bag)!r})
        except BagError as exc:
            print(exc)
            sys.exit(3)
        """
    )
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)


def test_when_metadata_is_an_alias_bomb_expect_refused_in_bounded_memory(tmp_path, speech):
    bag = speech_bag(tmp_path, speech)
    metadata = bag / "metadata.yaml"
    metadata.write_text(BOMB + metadata.read_text())
    result = read_in_a_bounded_process(bag)
    assert result.returncode == 3, result.stderr[-2000:]
    assert "metadata.yaml" in result.stdout
    assert "aliases" in result.stdout


@pytest.mark.parametrize("kind", ["fifo", "dev_zero"])
def test_when_a_bag_file_is_special_expect_refused_without_blocking(tmp_path, speech, kind):
    bag = speech_bag(tmp_path, speech)
    target = bag / "metadata.yaml" if kind == "fifo" else next(bag.glob("*.mcap"))
    target.unlink()
    if kind == "fifo":
        os.mkfifo(target)
    else:
        target.symlink_to("/dev/zero")
    result = read_in_a_bounded_process(bag)
    assert result.returncode == 3, result.stderr[-2000:]
    assert target.name in result.stdout
    assert "not a regular file" in result.stdout


def test_when_an_mcap_chunk_would_decompress_beyond_the_cap_expect_refused(
    tmp_path, speech, monkeypatch
):
    bag = speech_bag(tmp_path, speech)
    read_bag_audio(bag)  # a normal bag reads
    monkeypatch.setattr(bag_module, "MAX_CHUNK_BYTES_DECOMPRESSED", 1024)
    with pytest.raises(BagError, match=r"\.mcap: a chunk would decompress to \d+ bytes"):
        read_bag_audio(bag)


def test_when_a_compressed_file_hides_its_size_expect_refused(tmp_path):
    folder = tmp_path / "bag"
    folder.mkdir()
    (folder / "bag_0.db3.zstd").write_bytes(b"\x28\xb5\x2f\xfd\x00\x00\x00\x00")  # no size
    with pytest.raises(BagError, match=r"bag_0\.db3\.zstd: decompresses to an unknown size"):
        read_bag_audio(folder)

"""Hostile bag folders are refused within seconds and in bounded memory, naming the file.

A well-formed bag is hostile too when a topic holds a type its reader cannot decode, or when a
command would write into it: both are refused with one line, and a copied message always keeps
its own type.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from test_cli_errors import assert_one_line, audio2pose

from audio2pose_ros.data import bag as bag_module
from audio2pose_ros.data.bag import (
    AUDIO_DATA_TYPE,
    AUDIO_TOPIC,
    BagError,
    BagWriter,
    audio_messages,
    read_bag_audio,
    read_messages,
    typestore,
    write_audio_bag,
)

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


STAMPED_TYPE = "audio_common_msgs/msg/AudioDataStamped"
STRING_TYPE = "std_msgs/msg/String"


def stamped_audio_bag(path: Path, speech) -> Path:
    """A well-formed bag whose /audio/audio holds AudioDataStamped (a type the package knows)."""
    store = typestore()
    stamp = store.types["builtin_interfaces/msg/Time"](sec=0, nanosec=0)
    header = store.types["std_msgs/msg/Header"](stamp=stamp, frame_id="")
    with BagWriter(path) as bag:
        for m in audio_messages(speech[:16000]):
            if m.topic == AUDIO_TOPIC:
                audio = store.deserialize_cdr(m.data, m.msgtype)
                msg = store.types[STAMPED_TYPE](header=header, audio=audio)
                data = bytes(store.serialize_cdr(msg, STAMPED_TYPE))
                bag.write(m.topic, STAMPED_TYPE, m.timestamp_ns, data)
            else:
                bag.write(m.topic, m.msgtype, m.timestamp_ns, m.data)
    return path


def two_types_on_audio(path: Path, speech) -> Path:
    """/audio/audio recorded on two connections: AudioData, and one std_msgs/String message."""
    store = typestore()
    messages = audio_messages(speech[:16000])
    with Writer(path, version=8, storage_plugin=StoragePlugin.MCAP) as bag:
        connections = {
            (m.topic, m.msgtype): bag.add_connection(m.topic, m.msgtype, typestore=store)
            for m in messages[:2]
        }
        text = bag.add_connection(AUDIO_TOPIC, STRING_TYPE, typestore=store)
        for m in messages:
            bag.write(connections[m.topic, m.msgtype], m.timestamp_ns, m.data)
        hello = bytes(store.serialize_cdr(store.types[STRING_TYPE](data="hello"), STRING_TYPE))
        bag.write(text, messages[3].timestamp_ns, hello)
    return path


@pytest.mark.parametrize("verb", ["synth", "check-body", "check-head"])
@pytest.mark.parametrize(
    ("make", "found"),
    [(stamped_audio_bag, STAMPED_TYPE), (two_types_on_audio, STRING_TYPE)],
    ids=["AudioDataStamped", "String-beside-AudioData"],
)
def test_when_the_audio_topic_carries_another_known_type_expect_exit_1_naming_it(
    capsys, tmp_path, speech, verb, make, found
):
    bag = make(tmp_path / "bag", speech)
    argv = [verb, bag, *(["-o", tmp_path / "out.csv"] if verb == "synth" else [])]
    status, stderr = audio2pose(capsys, *argv)
    assert status == 1, stderr
    assert_one_line(stderr, rf"bag: {AUDIO_TOPIC} is {found}, expected {AUDIO_DATA_TYPE}")


def test_when_repairing_a_topic_recorded_with_two_types_expect_each_message_keeps_its_type(
    capsys, tmp_path, speech
):
    damaged = two_types_on_audio(tmp_path / "bag", speech)
    out = tmp_path / "repaired"
    status, stderr = audio2pose(capsys, "bag", "repair", damaged, "-o", out)
    assert status == 0, stderr
    before = sorted((m.timestamp_ns, m.msgtype, m.data) for m in read_messages(damaged))
    after = sorted((m.timestamp_ns, m.msgtype, m.data) for m in read_messages(out))
    assert after == before, "the repaired bag stores a message under another type"


def test_when_a_writer_gets_two_types_on_one_topic_expect_two_connections(tmp_path, speech):
    messages = audio_messages(speech[:1600])
    hello = typestore().serialize_cdr(typestore().types[STRING_TYPE](data="hi"), STRING_TYPE)
    with BagWriter(tmp_path / "bag") as bag:
        for m in messages:
            bag.write(m.topic, m.msgtype, m.timestamp_ns, m.data)
        bag.write(AUDIO_TOPIC, STRING_TYPE, messages[-1].timestamp_ns + 1, bytes(hello))
    assert bag.counts[AUDIO_TOPIC] == sum(m.topic == AUDIO_TOPIC for m in messages) + 1
    types = [m.msgtype for m in read_messages(tmp_path / "bag", [AUDIO_TOPIC])]
    assert types == [AUDIO_DATA_TYPE] * (len(types) - 1) + [STRING_TYPE]


@pytest.mark.parametrize("named", ["folder", "mcap file"])
def test_when_repair_would_write_inside_the_damaged_bag_expect_exit_2_and_it_kept(
    capsys, tmp_path, speech, named
):
    bag = speech_bag(tmp_path, speech)
    before = sorted(p.name for p in bag.iterdir())
    source = bag if named == "folder" else next(bag.glob("*.mcap"))
    status, stderr = audio2pose(capsys, "bag", "repair", source, "-o", bag / "repaired")
    assert sorted(p.name for p in bag.iterdir()) == before
    assert status == 2, stderr
    assert_one_line(stderr, r"-o \S+repaired: is inside (the folder \S+ of )?the input ")


@pytest.mark.parametrize("builder", [stamped_audio_bag, two_types_on_audio])
def test_when_a_bag_to_play_has_another_type_on_the_audio_topic_expect_it_refused(
    tmp_path, speech, builder
):
    """audio2pose run --play publishes the bag's bytes as AudioData: only AudioData may go."""
    from audio2pose_ros.ros.recorder import audio_source

    bag = builder(tmp_path / "bag", speech)
    with pytest.raises(
        BagError, match=r"/audio/audio is .*, expected audio_common_msgs/msg/AudioData"
    ):
        audio_source(bag)

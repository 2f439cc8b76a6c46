"""read_wav on hostile files: one clear InputError naming the file, memory bounded by its size
and the sample types it reads, checked against the standard library."""

from __future__ import annotations

import struct
import tracemalloc
import wave
from pathlib import Path

import numpy as np
import pytest

from audio2pose_ros.audio.pcm import PcmDecoder, PcmFormat
from audio2pose_ros.audio.wav import read_wav
from audio2pose_ros.errors import InputError, InvalidAudio, UnsupportedAudioFormat


def wav_bytes(
    channels: int = 1,
    rate: int = 16000,
    bits: int = 16,
    data: bytes = b"\x00\x10" * 1600,
    tag: int = 1,
    data_size: int | None = None,
    block_align: int | None = None,
    extra_chunks: bytes = b"",
) -> bytes:
    """A WAV file whose header says exactly what the arguments say, true or not."""
    block = channels * bits // 8 if block_align is None else block_align
    fmt = struct.pack("<HHIIHH", tag, channels, rate, rate * block, block, bits)
    size = len(data) if data_size is None else data_size
    body = b"WAVE" + b"fmt " + struct.pack("<I", len(fmt)) + fmt + extra_chunks
    body += b"data" + struct.pack("<I", size) + data
    return b"RIFF" + struct.pack("<I", len(body)) + body


def write(tmp_path: Path, content: bytes, name: str = "hostile.wav") -> Path:
    path = tmp_path / name
    path.write_bytes(content)
    return path


@pytest.mark.parametrize(
    ("content", "error", "match"),
    [
        (wav_bytes(channels=0), UnsupportedAudioFormat, "channels 0;"),
        (wav_bytes()[:20], InvalidAudio, "no 'fmt ' chunk|'fmt ' chunk of"),
        (b"RIFF" + struct.pack("<I", 12) + b"WAVEfmt " + b"\0" * 4, InvalidAudio, "'fmt ' chunk"),
        (wav_bytes(rate=1), UnsupportedAudioFormat, "sample_rate 1;"),
        (wav_bytes(rate=383999), UnsupportedAudioFormat, "sample_rate 383999;"),
        (wav_bytes(rate=47999), UnsupportedAudioFormat, "47999: resampling it to 16000 Hz"),
        (wav_bytes(channels=300, data=b"\0" * 600), UnsupportedAudioFormat, "channels 300"),
        (wav_bytes(bits=12), UnsupportedAudioFormat, "12 bits"),
        (wav_bytes(tag=0x55), UnsupportedAudioFormat, "format tag 0x0055"),  # mp3 in a WAV
        (wav_bytes(block_align=3), UnsupportedAudioFormat, "block_align 3"),
        (wav_bytes(data=b""), InvalidAudio, "holds no samples"),
        (b"ID3\x03" + b"\0" * 100, InvalidAudio, "not a RIFF/WAVE file"),
        (b"", InvalidAudio, "not a RIFF/WAVE file"),
        (wav_bytes()[:36], InvalidAudio, "no 'data' chunk"),
        (
            wav_bytes(tag=3, bits=32, data=struct.pack("<2f", 0.1, float("nan"))),
            InvalidAudio,
            "non-finite",
        ),
    ],
)
def test_when_wav_is_hostile_expect_one_input_error_naming_the_file(
    tmp_path, content, error, match
):
    path = write(tmp_path, content)
    with pytest.raises(error, match=match) as caught:
        read_wav(path)
    message = str(caught.value)
    assert message.startswith(f"{path}: ")
    assert "\n" not in message
    assert isinstance(caught.value, InputError)


def test_when_wav_is_missing_expect_input_error_naming_it(tmp_path):
    with pytest.raises(InputError, match=r"missing\.wav: cannot read WAV file: No such file"):
        read_wav(tmp_path / "missing.wav")


def test_when_wav_header_claims_4_gib_of_data_expect_memory_bounded_by_the_file(tmp_path):
    data = b"\x00\x10" * 8000  # 0.5 s really present
    path = write(tmp_path, wav_bytes(data=data, data_size=0xFFFFFFF0))
    tracemalloc.start()
    samples, rate = read_wav(path)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert (samples.size, rate) == (8000, 16000)
    assert peak < 4 << 20


def test_when_wav_claims_1_hz_expect_refused_without_allocating(tmp_path):
    path = write(tmp_path, wav_bytes(rate=1, data=b"\x01\x00" * 400000))
    tracemalloc.start()
    with pytest.raises(UnsupportedAudioFormat):
        read_wav(path)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 8 << 20  # the file (800 kB) and little more; it was 48 GiB


def test_when_wav_decoded_in_blocks_expect_same_samples_as_one_feed(tmp_path):
    rate = 44100
    rng = np.random.default_rng(3)
    values = (rng.uniform(-0.8, 0.8, size=(3 * rate, 2)) * 32767).astype("<i2")
    path = write(tmp_path, wav_bytes(channels=2, rate=rate, data=values.tobytes()))
    samples, original = read_wav(path)
    decoder = PcmDecoder(PcmFormat("S16LE", 2, rate))
    whole = np.concatenate([decoder.feed(values.tobytes()), decoder.flush()])
    assert original == rate
    np.testing.assert_allclose(samples, whole, rtol=0, atol=1e-6)


@pytest.mark.parametrize("sampwidth", [1, 2, 3, 4])
def test_when_integer_wav_written_by_the_wave_module_expect_its_scaled_values(tmp_path, sampwidth):
    rng = np.random.default_rng(sampwidth)
    bits = 8 * sampwidth
    ints = rng.integers(-(2 ** (bits - 1)), 2 ** (bits - 1), size=(400, 2))
    if sampwidth == 1:
        raw = (ints + 128).astype(np.uint8).tobytes()  # 8-bit WAV is unsigned
    else:
        raw = b"".join(int(v).to_bytes(sampwidth, "little", signed=True) for v in ints.ravel())
    path = tmp_path / "w.wav"
    with wave.open(str(path), "wb") as w:
        w.setnchannels(2)
        w.setsampwidth(sampwidth)
        w.setframerate(16000)
        w.writeframes(raw)
    samples, _ = read_wav(path)
    expected = ints.mean(axis=1) / 2 ** (bits - 1)
    np.testing.assert_allclose(samples, expected, rtol=0, atol=1e-6)


def test_when_float64_extensible_wav_with_extra_chunks_expect_samples(tmp_path):
    values = np.array([0.5, -0.25, 0.125, 2.0])
    ext = struct.pack("<HHIIHHHHI", 0xFFFE, 1, 16000, 16000 * 8, 8, 64, 22, 64, 0)
    ext += struct.pack("<H", 3) + b"\x00\x00\x00\x00\x10\x00\x80\x00\x00\xaa\x00\x38\x9b\x71"
    list_chunk = b"LIST" + struct.pack("<I", 5) + b"abcde" + b"\0"  # odd size: padded
    body = b"WAVE" + b"fmt " + struct.pack("<I", len(ext)) + ext + list_chunk
    body += b"data" + struct.pack("<I", 32) + values.astype("<f8").tobytes()
    path = write(tmp_path, b"RIFF" + struct.pack("<I", len(body)) + body)
    samples, rate = read_wav(path)
    assert rate == 16000
    below_one = np.nextafter(np.float32(1), np.float32(0))  # output range is [-1, 1)
    np.testing.assert_array_equal(samples, np.float32([0.5, -0.25, 0.125, below_one]))


def test_when_many_random_corruptions_expect_only_input_errors(tmp_path):
    good = wav_bytes(channels=2, rate=44100, data=b"\x01\x02" * 2000)
    rng = np.random.default_rng(11)
    path = tmp_path / "fuzz.wav"
    outcomes, messages = set(), []
    for _ in range(400):
        content = bytearray(good[: int(rng.integers(0, len(good) + 1))])
        for _ in range(int(rng.integers(1, 4))):
            if content:
                content[int(rng.integers(0, min(len(content), 48)))] = int(rng.integers(256))
        path.write_bytes(bytes(content))
        try:
            read_wav(path)
            outcomes.add("read")
        except InputError as exc:
            messages.append(str(exc))
            outcomes.add(type(exc).__name__)
    assert {"read", "InvalidAudio", "UnsupportedAudioFormat"} <= outcomes
    assert all(message.startswith(f"{path}: ") for message in messages)

"""Tests of audio2pose_ros.audio.pcm: AudioData bytes -> 16 kHz mono float32 (seed 003 4.2.2)."""

from __future__ import annotations

import array
import struct
import wave

import numpy as np
import pytest

from audio2pose_ros.audio.pcm import PcmDecoder, PcmFormat, encode_pcm
from audio2pose_ros.audio.resample import PolyphaseResampler
from audio2pose_ros.audio.wav import read_wav
from audio2pose_ros.errors import InputError, InvalidAudio, UnsupportedAudioFormat
from audio2pose_ros.resources import bundled_speech_path


def decode_chunked(decoder: PcmDecoder, data: bytes, sizes: list[int]) -> np.ndarray:
    """Feed ``data`` in pieces of the given sizes (cycled), then flush."""
    out, i, j = [], 0, 0
    while i < len(data):
        size = sizes[j % len(sizes)]
        out.append(decoder.feed(data[i : i + size]))
        i += size
        j += 1
    out.append(decoder.flush())
    return np.concatenate(out)


def random_sizes(seed: int, count: int = 500, high: int = 1500, odd: bool = True) -> list[int]:
    sizes = np.random.default_rng(seed).integers(1, high, size=count)
    return [int(2 * (s // 2) + 1) if odd else int(s) for s in sizes]


@pytest.mark.parametrize(
    ("sample_format", "payload", "expected"),
    [
        ("S16LE", struct.pack("<4h", 0, 16384, -32768, 32767), [0.0, 0.5, -1.0, 32767 / 32768]),
        ("S32LE", struct.pack("<3i", 1 << 30, -(1 << 31), -(1 << 29)), [0.5, -1.0, -0.25]),
        ("F32LE", struct.pack("<3f", 0.25, -0.75, 0.0), [0.25, -0.75, 0.0]),
        ("U8", bytes([128, 192, 0, 64]), [0.0, 0.5, -1.0, -0.5]),
    ],
)
def test_when_each_format_decoded_expect_hand_computed_values(sample_format, payload, expected):
    decoder = PcmDecoder(PcmFormat(sample_format, 1, 16000))
    out = decoder.feed(payload)
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out, np.asarray(expected, dtype=np.float32))
    assert decoder.pending_bytes == 0


def test_when_stereo_expect_channels_averaged():
    payload = struct.pack("<6h", 16384, -16384, 16384, 0, -32768, -32768)
    out = PcmDecoder(PcmFormat("S16LE", 2, 16000)).feed(payload)
    np.testing.assert_array_equal(out, np.array([0.0, 0.25, -1.0], dtype=np.float32))


def test_when_empty_bytes_fed_expect_empty_float32_array():
    out = PcmDecoder(PcmFormat()).feed(b"")
    assert out.shape == (0,)
    assert out.dtype == np.float32


def test_when_partial_frame_fed_expect_pending_bytes_until_completed_and_reset_clears():
    decoder = PcmDecoder(PcmFormat("S32LE", 2, 16000))  # 8-byte frames
    payload = struct.pack("<2i", 1 << 30, 1 << 29)
    assert decoder.feed(payload[:5]).size == 0
    assert decoder.pending_bytes == 5
    np.testing.assert_array_equal(decoder.feed(payload[5:]), np.array([0.375], dtype=np.float32))
    assert decoder.pending_bytes == 0
    decoder.feed(payload[:3])
    decoder.reset()
    assert decoder.pending_bytes == 0
    np.testing.assert_array_equal(decoder.feed(payload), np.array([0.375], dtype=np.float32))


def test_when_fed_array_memoryview_or_list_expect_same_as_bytes():
    payload = struct.pack("<3h", 1, -2, 300)
    expected = PcmDecoder(PcmFormat()).feed(payload)
    for data in (bytearray(payload), memoryview(payload), array.array("B", payload), list(payload)):
        np.testing.assert_array_equal(PcmDecoder(PcmFormat()).feed(data), expected)


@pytest.mark.parametrize("rate", [16000, 44100])
def test_when_bytes_arrive_in_odd_and_single_byte_chunks_expect_same_samples_as_whole(rate):
    rng = np.random.default_rng(7)
    fmt = PcmFormat("S16LE", 2, rate)
    payload = encode_pcm(rng.uniform(-0.5, 0.5, size=(rate // 10, 2)), fmt)
    whole = decode_chunked(PcmDecoder(fmt), payload, [len(payload)])
    odd = decode_chunked(PcmDecoder(fmt), payload, random_sizes(1))
    single = decode_chunked(PcmDecoder(fmt), payload, [1])
    assert whole.size == -(-(rate // 10) * 16000 // rate)
    np.testing.assert_allclose(odd, whole, rtol=0, atol=1e-6)
    np.testing.assert_allclose(single, whole, rtol=0, atol=1e-6)


@pytest.mark.parametrize("rate", [44100, 48000, 8000])
def test_when_440hz_sine_resampled_expect_16k_sine_of_same_frequency_and_phase(rate):
    n = rate  # one second
    sine = 0.5 * np.sin(2 * np.pi * 440.0 * np.arange(n) / rate)
    fmt = PcmFormat("F32LE", 1, rate)
    out = decode_chunked(PcmDecoder(fmt), encode_pcm(sine, fmt), [len(sine) * 4])
    assert out.size == 16000
    spectrum = np.abs(np.fft.rfft(out * np.hanning(out.size)))
    assert np.argmax(spectrum) * 16000 / out.size == pytest.approx(440.0, abs=1.0)
    # delay-compensated: sample m is the input at time m / 16 kHz (edges see zero padding)
    expected = 0.5 * np.sin(2 * np.pi * 440.0 * np.arange(out.size) / 16000)
    np.testing.assert_allclose(out[200:-200], expected[200:-200], rtol=0, atol=1e-4)


@pytest.mark.parametrize("rate", [44100, 48000, 22050, 8000])
def test_when_resampled_stream_chunked_expect_equal_to_whole_signal(rate):
    rng = np.random.default_rng(rate)
    fmt = PcmFormat("S16LE", 1, rate)
    payload = encode_pcm(rng.uniform(-0.9, 0.9, size=rate // 2), fmt)
    whole = decode_chunked(PcmDecoder(fmt), payload, [len(payload)])
    chunked = decode_chunked(PcmDecoder(fmt), payload, random_sizes(rate, high=900))
    assert chunked.size == whole.size == -(-(rate // 2) * 16000 // rate)
    np.testing.assert_allclose(chunked, whole, rtol=0, atol=1e-6)


def test_when_resampler_delay_known_expect_output_held_back_until_flush():
    resampler = PolyphaseResampler(48000, 16000)
    out = resampler.process(np.ones(4800))
    assert out.size == 1600 - resampler.delay_samples
    assert resampler.flush().size == resampler.delay_samples
    np.testing.assert_allclose(out[resampler.delay_samples * 2 :], 1.0, atol=1e-3)


@pytest.mark.parametrize(
    ("field", "kwargs", "match"),
    [
        ("sample_format", {"sample_format": "S24LE"}, r"sample_format 'S24LE'.*S16LE, S32LE"),
        ("coding_format", {"coding_format": "mp3"}, r"coding_format 'mp3'.*'wave'"),
        ("channels", {"channels": 0}, r"channels 0.*1\.\.16"),
        ("channels", {"channels": 255}, r"channels 255.*1\.\.16"),
        ("channels", {"channels": True}, r"channels True"),
        ("sample_rate", {"sample_rate": 0}, r"sample_rate 0.*integer Hz in 8000\.\.192000"),
        ("sample_rate", {"sample_rate": 1}, r"sample_rate 1;"),
        ("sample_rate", {"sample_rate": 7999}, r"sample_rate 7999;"),
        ("sample_rate", {"sample_rate": 192001}, r"sample_rate 192001;"),
        ("sample_rate", {"sample_rate": 383999}, r"sample_rate 383999;"),
        ("sample_format", {"sample_format": "\x00garbage\xff"}, r"unsupported sample_format"),
    ],
)
def test_when_audio_info_field_unsupported_expect_unsupported_audio_format(field, kwargs, match):
    info = {"channels": 1, "sample_rate": 16000, "sample_format": "S16LE", "coding_format": "wave"}
    info.update(kwargs)
    with pytest.raises(UnsupportedAudioFormat, match=match):
        PcmFormat.from_audio_info(**info)
    assert issubclass(UnsupportedAudioFormat, InputError), field
    assert not issubclass(UnsupportedAudioFormat, ValueError), field


def test_when_audio_info_strings_in_other_case_expect_accepted_and_normalised():
    fmt = PcmFormat.from_audio_info(2, 48000, "s16le", "WAVE")
    assert (fmt.sample_format, fmt.coding_format, fmt.frame_bytes) == ("S16LE", "wave", 4)
    assert PcmFormat.from_audio_info(1, 16000, "F32LE", "").coding_format == ""


@pytest.mark.parametrize("rate", [16000, 48000])
@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_when_f32_chunk_has_non_finite_sample_expect_invalid_audio_and_state_unchanged(rate, bad):
    fmt = PcmFormat("F32LE", 1, rate)
    rng = np.random.default_rng(3)
    first, second = rng.uniform(-0.5, 0.5, size=(2, rate // 20))
    poisoned = rng.uniform(-0.5, 0.5, size=rate // 50)
    poisoned[7] = bad
    decoder = PcmDecoder(fmt)
    outs = [decoder.feed(encode_pcm(first, fmt))]
    with pytest.raises(InvalidAudio, match="non-finite"):
        decoder.feed(struct.pack(f"<{poisoned.size}f", *poisoned))
    outs += [decoder.feed(encode_pcm(second, fmt)), decoder.flush()]
    reference = PcmDecoder(fmt)
    expected = [reference.feed(encode_pcm(first, fmt)), reference.feed(encode_pcm(second, fmt))]
    expected.append(reference.flush())
    np.testing.assert_array_equal(np.concatenate(outs), np.concatenate(expected))


def test_when_non_finite_chunk_splits_a_frame_expect_frame_alignment_kept():
    fmt = PcmFormat("F32LE", 1, 16000)
    payload = struct.pack("<5f", 0.1, 0.2, float("nan"), 0.4, 0.5)
    decoder = PcmDecoder(fmt)
    first = decoder.feed(payload[:6])  # 0.1 and half of 0.2
    with pytest.raises(InvalidAudio):
        decoder.feed(payload[6:14])  # rest of 0.2, NaN, half of 0.4: frames dropped
    rest = decoder.feed(payload[14:])  # rest of 0.4, 0.5
    np.testing.assert_array_equal(first, np.array([0.1], dtype=np.float32))
    np.testing.assert_array_equal(rest, np.array([0.4, 0.5], dtype=np.float32))


def test_when_float_samples_exceed_full_scale_expect_clipped_to_minus_one_one():
    fmt = PcmFormat("F32LE", 1, 16000)
    out = PcmDecoder(fmt).feed(struct.pack("<3f", 1.5, -3.0, 1.0))
    assert out[1] == -1.0
    assert (out < 1.0).all()
    assert out[0] == pytest.approx(1.0, abs=1e-6)
    full = PcmDecoder(PcmFormat("S32LE", 1, 16000)).feed(struct.pack("<i", (1 << 31) - 1))
    assert full[0] < 1.0  # (2**31 - 1) / 2**31 would round to 1.0 in float32


@pytest.mark.parametrize(
    ("sample_format", "step"),
    [("S16LE", 2**-15), ("S32LE", 2**-31), ("F32LE", 1e-7), ("U8", 2**-7)],
)
@pytest.mark.parametrize("channels", [1, 2])
def test_when_encoded_then_decoded_expect_round_trip_within_quantisation(
    sample_format, step, channels
):
    fmt = PcmFormat(sample_format, channels, 16000)
    x = np.random.default_rng(5).uniform(-1.0, 0.99, size=257)
    payload = encode_pcm(x, fmt)
    assert len(payload) == x.size * fmt.frame_bytes
    out = PcmDecoder(fmt).feed(payload)
    np.testing.assert_allclose(out, x, rtol=0, atol=step / 2 + 1e-7)


def test_when_encode_given_wrong_shape_or_nan_expect_errors():
    with pytest.raises(ValueError, match=r"shape \(n,\) or \(n, 2\)"):
        encode_pcm(np.zeros((4, 3)), PcmFormat("S16LE", 2))
    with pytest.raises(InvalidAudio):
        encode_pcm(np.array([0.0, np.nan]), PcmFormat())


def test_when_read_wav_48k_stereo_expect_16k_mono_and_original_rate(tmp_path):
    rate, n = 48000, 4800
    t = np.arange(n) / rate
    left, right = 0.5 * np.sin(2 * np.pi * 440 * t), 0.1 * np.sin(2 * np.pi * 440 * t)
    path = tmp_path / "stereo.wav"
    with wave.open(str(path), "wb") as w:
        w.setnchannels(2)
        w.setsampwidth(2)
        w.setframerate(rate)
        w.writeframes(encode_pcm(np.stack([left, right], axis=1), PcmFormat("S16LE", 2, rate)))
    samples, original = read_wav(path)
    assert original == rate
    assert samples.dtype == np.float32
    assert samples.shape == (1600,)
    expected = 0.3 * np.sin(2 * np.pi * 440 * np.arange(1600) / 16000)
    np.testing.assert_allclose(samples[100:-100], expected[100:-100], rtol=0, atol=2e-4)


def test_when_read_wav_at_16k_expect_exact_int16_over_32768():
    path = bundled_speech_path("librivox_sense_and_sensibility_01_0880.wav")
    samples, rate = read_wav(path)
    with wave.open(str(path), "rb") as w:
        raw = np.frombuffer(w.readframes(w.getnframes()), dtype="<i2")
    assert rate == 16000
    np.testing.assert_array_equal(samples, raw.astype(np.float32) / 32768.0)


def test_when_format_written_as_audio_info_expect_from_audio_info_gives_it_back():
    from audio2pose_ros.audio.pcm import S16LE_MONO_16K

    fields = S16LE_MONO_16K.audio_info_fields()
    assert fields["bitrate"] == 256000  # 16 kHz x 16 bit x 1 channel, as audio_capture reports
    fields.pop("bitrate")
    assert PcmFormat.from_audio_info(**fields) == S16LE_MONO_16K
    stereo = PcmFormat("F32LE", 2, 48000)
    assert stereo.audio_info_fields()["bitrate"] == 48000 * 2 * 4 * 8


def test_when_every_s16_value_decoded_mono_or_stereo_expect_the_same_float32_samples():
    """Mono S16LE at 16 kHz takes a direct path; it gives what the averaging path gives."""
    values = np.arange(-32768, 32768, dtype=np.int16)
    mono = PcmDecoder(PcmFormat("S16LE", 1, 16000, "wave")).feed(values.tobytes())
    stereo = PcmDecoder(PcmFormat("S16LE", 2, 16000, "wave")).feed(np.repeat(values, 2).tobytes())
    assert mono.dtype == stereo.dtype == np.float32
    assert np.array_equal(mono.view(np.int32), stereo.view(np.int32))
    assert mono.min() == -1.0
    assert mono.max() < 1.0

"""Tests of audio2pose_ros.audio.source: every field of AudioInfo, AudioData and AudioBuffer as an
attacker would set it, and the per-message and per-second limits."""

from __future__ import annotations

import struct
import time
import tracemalloc

import numpy as np
import pytest

from audio2pose_ros.audio.pcm import PcmDecoder, PcmFormat, encode_pcm
from audio2pose_ros.audio.source import (
    AudioBudget,
    AudioDropped,
    AudioInput,
    AudioInputSettings,
    ChannelSelection,
)
from audio2pose_ros.errors import (
    ConfigurationError,
    InputError,
    InvalidAudio,
    UnsupportedAudioFormat,
)

S16_INFO = {"channels": 1, "sample_rate": 16000, "sample_format": "S16LE", "coding_format": "wave"}
PEPPER_MAP = (3, 5, 0, 2)  # naoqi_driver on Pepper: rear left, rear right, front left, front right


class FakeClock:
    """A monotonic clock the test moves by hand (seconds)."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def audio_input(clock: FakeClock | None = None, **settings: object) -> AudioInput:
    return AudioInput(AudioInputSettings(**settings), clock=clock or FakeClock())


def s16(n: int, value: int = 1000) -> bytes:
    return struct.pack(f"<{n}h", *([value] * n))


@pytest.mark.parametrize("rate", [1, 7999, 192001, 383999, 47999])
def test_when_audio_info_claims_a_bomb_rate_expect_refused_at_once_with_little_memory(rate):
    source = audio_input()
    tracemalloc.start()
    start = time.process_time()
    with pytest.raises(UnsupportedAudioFormat, match=rf"AudioInfo rejected: .*sample_rate {rate}"):
        source.set_audio_info(1, rate, "S16LE", "wave")
    with pytest.raises(AudioDropped, match=rf"AudioInfo rejected: .*sample_rate {rate}"):
        source.decode_audio_data(s16(1 << 19))  # the 1 MiB message that used to allocate 62 GiB
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert time.process_time() - start < 0.5  # CPU time: a loaded machine does not add to it
    assert peak < 16 << 20
    assert source.info_rejected
    assert source.format is None


def test_when_audio_info_rejected_expect_reason_kept_until_a_valid_one_then_recovery():
    source = audio_input()
    with pytest.raises(AudioDropped, match="no usable AudioInfo received yet"):
        source.decode_audio_data(s16(160))
    with pytest.raises(UnsupportedAudioFormat):
        source.set_audio_info(1, 16000, "S16LE", "mp3")
    for _ in range(3):  # the reason is not replaced by "no usable AudioInfo received yet"
        with pytest.raises(AudioDropped, match="AudioInfo rejected: unsupported coding_format"):
            source.decode_audio_data(s16(160))
    assert "coding_format 'mp3'" in source.format_problem
    assert source.set_audio_info(**S16_INFO) is True
    assert source.format_problem == ""
    assert not source.info_rejected
    np.testing.assert_allclose(source.decode_audio_data(s16(160)), 1000 / 32768)
    assert source.dropped_chunks == 4
    assert source.chunks == 5


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("channels", 0, "channels 0"),
        ("channels", 255, "channels 255"),
        ("sample_format", "S24LE", "sample_format 'S24LE'"),
        ("sample_format", "\x00\xff" * 100, "unsupported sample_format"),
        ("sample_format", "", "unsupported sample_format ''"),
        ("coding_format", "mp3", "coding_format 'mp3'"),
        ("coding_format", "flac", "coding_format 'flac'"),
        ("sample_rate", 0, "sample_rate 0"),
        ("sample_rate", 2**31 - 1, "sample_rate 2147483647"),
    ],
)
def test_when_an_audio_info_field_is_hostile_expect_input_error_naming_it(field, value, match):
    info = dict(S16_INFO, **{field: value})
    with pytest.raises(UnsupportedAudioFormat, match=match) as caught:
        audio_input().set_audio_info(**info)
    assert isinstance(caught.value, InputError)
    assert not isinstance(caught.value, ValueError)


def test_when_the_same_audio_info_repeats_expect_no_restart():
    source = audio_input()
    assert source.set_audio_info(**S16_INFO) is True
    assert source.set_audio_info(**S16_INFO) is False
    assert (
        source.set_audio_info(**dict(S16_INFO, sample_format="s16le", coding_format="WAVE"))
        is False
    )


def test_when_message_over_max_chunk_bytes_expect_dropped_before_decoding():
    source = audio_input(max_chunk_bytes=4096)
    source.set_audio_info(**S16_INFO)
    with pytest.raises(
        AudioDropped, match=r"AudioData message of 4098 bytes \(max_chunk_bytes 4096\)"
    ):
        source.decode_audio_data(s16(2049))
    assert source.decode_audio_data(s16(2048)).size == 2048


def test_when_message_longer_than_max_chunk_s_expect_dropped_and_next_one_decoded():
    source = audio_input(max_chunk_s=0.5)
    source.set_audio_info(**dict(S16_INFO, sample_rate=8000))  # 8 kHz: output twice the input
    with pytest.raises(AudioDropped, match=r"AudioData message of 0\.501 s \(max_chunk_s 0\.5\)"):
        source.decode_audio_data(s16(4008))
    assert source.dropped_bytes == 8016
    out = source.decode_audio_data(s16(4000))
    assert 0 < out.size <= 8000  # never more than max_chunk_s of output per message


def test_when_audio_floods_faster_than_budget_expect_excess_dropped_and_recovery():
    clock = FakeClock()
    source = audio_input(clock, max_audio_s_per_s=2.0, max_chunk_s=1.0)
    source.set_audio_info(**S16_INFO)
    second = s16(16000)
    source.decode_audio_data(second)
    source.decode_audio_data(second)  # the bucket holds 2 s
    with pytest.raises(AudioDropped, match="faster than max_audio_s_per_s 2"):
        source.decode_audio_data(second)
    clock.now += 0.5  # refills 1 s of audio
    assert source.decode_audio_data(second).size == 16000


def test_when_f32_holds_nan_then_good_audio_expect_drop_then_decoding_goes_on():
    source = audio_input()
    source.set_audio_info(**dict(S16_INFO, sample_format="F32LE"))
    with pytest.raises(InvalidAudio, match="non-finite"):
        source.decode_audio_data(struct.pack("<3f", 0.1, float("nan"), 0.2))
    np.testing.assert_allclose(source.decode_audio_data(struct.pack("<2f", 0.5, -0.5)), [0.5, -0.5])


def test_when_f32_holds_denormals_and_huge_values_expect_bounded_output_without_ringing():
    rate = 48000
    source = audio_input()
    source.set_audio_info(**dict(S16_INFO, sample_format="F32LE", sample_rate=rate))
    tiny = np.full(rate, np.float32(1e-45))  # float32 denormals
    tiny[rate // 2] = 3e38  # one wild finite value
    start = time.process_time()
    out = source.decode_audio_data(tiny.astype("<f4").tobytes())
    assert time.process_time() - start < 0.5
    assert np.all(np.isfinite(out))
    assert np.all(np.abs(out) <= 1.0)
    # clipped to full scale before filtering: the spike rings as a full-scale click would
    # (under 0.5), where 3e38 saturated 65 output samples at full scale before
    assert np.count_nonzero(np.abs(out) > 0.5) == 0
    assert np.max(np.abs(out[: out.size // 2 - 1600])) < 1e-3


def test_when_odd_byte_counts_arrive_expect_partial_frame_kept_for_the_next_message():
    source = audio_input()
    source.set_audio_info(**dict(S16_INFO, channels=2))
    payload = s16(8, 2000)
    assert source.decode_audio_data(payload[:5]).size == 1
    assert source.decode_audio_data(payload[5:]).size == 3


def test_when_format_flips_every_message_expect_each_decoded_in_bounded_time():
    source = audio_input(max_audio_s_per_s=100.0)
    infos = [dict(S16_INFO, sample_rate=r) for r in (44100, 48000, 11025, 22050)]
    start = time.process_time()
    restarts = 0
    for i in range(200):
        restarts += source.set_audio_info(**infos[i % len(infos)])
        source.decode_audio_data(s16(441))
    assert restarts == 200
    assert time.process_time() - start < 3.0  # filter designs are cached, not redone


def test_when_a_maximal_message_is_decoded_expect_memory_of_a_few_times_its_size():
    source = audio_input(max_chunk_s=60.0, max_audio_s_per_s=100.0)
    source.set_audio_info(**dict(S16_INFO, sample_rate=192000, channels=16))
    tracemalloc.start()
    source.decode_audio_data(bytes(1 << 20))  # the default max_chunk_bytes
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 48 << 20


# --- naoqi AudioBuffer -------------------------------------------------------------------------


def pepper_buffer(n_frames: int, channel_values: tuple[int, ...] = (100, 200, 300, 400)) -> list:
    return list(np.tile(np.asarray(channel_values, dtype=np.int16), n_frames))


@pytest.mark.parametrize(
    ("channels", "expected"),
    [
        ("mean", 250),
        ("0", 100),
        ("1,3", 300),
        ("front_left", 300),  # position 2 in Pepper's map
        ("rear_left,rear_right", 150),
    ],
)
def test_when_audio_buffer_channels_selected_expect_their_mean(channels, expected):
    source = audio_input(input_type="naoqi", channels=channels)
    out, changed = source.decode_audio_buffer(16000, PEPPER_MAP, pepper_buffer(160))
    assert changed
    np.testing.assert_allclose(out, expected / 32768, rtol=1e-6)


def test_when_audio_buffer_at_48k_with_4_channels_expect_16k_mono():
    source = audio_input(input_type="naoqi")
    t = np.arange(48000) / 48000
    tone = (8000 * np.sin(2 * np.pi * 300 * t)).astype(np.int16)
    data = np.repeat(tone, 4)
    out = np.concatenate(
        [
            source.decode_audio_buffer(48000, PEPPER_MAP, data[i : i + 16384])[0]
            for i in range(0, data.size, 16384)
        ]
    )
    expected = PcmDecoder(PcmFormat("S16LE", 1, 48000)).feed(tone.astype("<i2").tobytes())
    np.testing.assert_allclose(out, expected, atol=1e-6)


@pytest.mark.parametrize(
    ("frequency", "channel_map", "n_values", "error", "match"),
    [
        (0, PEPPER_MAP, 400, UnsupportedAudioFormat, "sample_rate 0"),
        (65535, PEPPER_MAP, 400, UnsupportedAudioFormat, "sample_rate 65535"),
        (48000, (), 400, UnsupportedAudioFormat, "empty channel_map"),
        (48000, tuple(range(17)), 17 * 10, UnsupportedAudioFormat, "channels 17"),
        (48000, PEPPER_MAP, 401, InvalidAudio, "401 samples are not whole frames of 4"),
    ],
)
def test_when_audio_buffer_fields_are_hostile_expect_dropped_with_the_reason(
    frequency, channel_map, n_values, error, match
):
    source = audio_input(input_type="naoqi")
    with pytest.raises(error, match=match):
        source.decode_audio_buffer(frequency, channel_map, [0] * n_values)
    assert source.dropped_chunks == 1
    out, _ = source.decode_audio_buffer(48000, PEPPER_MAP, [0] * 4800)
    assert out.size > 0  # the next good buffer is decoded


def test_when_named_channel_missing_from_channel_map_expect_refusal_naming_the_map():
    source = audio_input(input_type="naoqi", channels="front_center")
    with pytest.raises(UnsupportedAudioFormat, match=r"\['front_center'\] not in .*'rear_left'"):
        source.decode_audio_buffer(48000, PEPPER_MAP, [0] * 400)
    _out, _ = source.decode_audio_buffer(48000, (0, 2, 1, 4), [0] * 400)  # NAO's map has it
    assert source.channels_used == (2,)


def test_when_channel_map_changes_expect_restart_flag():
    source = audio_input(input_type="naoqi")
    assert source.decode_audio_buffer(48000, PEPPER_MAP, [0] * 400)[1] is True
    assert source.decode_audio_buffer(48000, PEPPER_MAP, [0] * 400)[1] is False
    assert source.decode_audio_buffer(48000, (0, 2, 1, 4), [0] * 400)[1] is True
    assert source.decode_audio_buffer(16000, (0, 2, 1, 4), [0] * 400)[1] is True


def test_when_audio_buffer_over_max_chunk_bytes_expect_dropped_before_conversion():
    source = audio_input(input_type="naoqi", max_chunk_bytes=1024)
    with pytest.raises(AudioDropped, match="dropped an AudioBuffer message of 1032 bytes"):
        source.decode_audio_buffer(48000, PEPPER_MAP, [0] * 516)


# --- settings and channel selection ------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("mean", ChannelSelection()),
        (" ALL ", ChannelSelection()),
        ("0", ChannelSelection(indices=(0,))),
        ("2, 0", ChannelSelection(indices=(2, 0))),
        ("Front_Left,rear_right", ChannelSelection(names=("front_left", "rear_right"))),
    ],
)
def test_when_channels_parameter_parsed_expect_selection(text, expected):
    assert ChannelSelection.parse(text) == expected


@pytest.mark.parametrize("text", ["", "-1", "16", "0,0", "left", "0,front_left", "[0]"])
def test_when_channels_parameter_is_bad_expect_configuration_error_naming_it(text):
    with pytest.raises(ConfigurationError, match=r"parameter channels: value .* allowed: 'mean'"):
        ChannelSelection.parse(text)


@pytest.mark.parametrize(
    ("settings", "match"),
    [
        ({"channels": "front_left"}, "only AudioBuffer carries"),
        ({"input_type": "alsa"}, "parameter input_type: value 'alsa' is not allowed"),
        ({"max_chunk_s": float("nan")}, "parameter max_chunk_s: value nan is not finite"),
        ({"max_chunk_bytes": 0}, "parameter max_chunk_bytes: value 0 is out of range"),
        ({"max_audio_s_per_s": float("inf")}, "max_audio_s_per_s: value inf is not finite"),
    ],
)
def test_when_input_settings_are_bad_expect_configuration_error(settings, match):
    with pytest.raises(ConfigurationError, match=match):
        AudioInputSettings(**settings)


def test_when_channels_change_live_expect_next_message_uses_them():
    source = audio_input(input_type="naoqi")
    source.decode_audio_buffer(16000, PEPPER_MAP, pepper_buffer(160))
    source.update_settings(AudioInputSettings(input_type="naoqi", channels="rear_right"))
    out, _ = source.decode_audio_buffer(16000, PEPPER_MAP, pepper_buffer(160))
    np.testing.assert_allclose(out, 200 / 32768, rtol=1e-6)
    with pytest.raises(ConfigurationError, match="input_type cannot change"):
        source.update_settings(AudioInputSettings())


def test_when_budget_clock_goes_backwards_expect_no_extra_audio():
    clock = FakeClock()
    budget = AudioBudget(1.0, 1.0, clock)
    assert budget.take(1.0)
    clock.now -= 50.0
    assert not budget.take(0.1)


def test_when_stereo_pcm_encoded_and_decoded_through_the_input_expect_channels_averaged():
    source = audio_input()
    source.set_audio_info(**dict(S16_INFO, channels=2))
    payload = encode_pcm(np.array([[0.5, 0.25], [-0.5, 0.0]]), PcmFormat("S16LE", 2))
    np.testing.assert_allclose(source.decode_audio_data(payload), [0.375, -0.25])


def test_when_live_channels_do_not_exist_in_the_current_audio_expect_refused_and_unchanged():
    source = audio_input()
    source.set_audio_info(**S16_INFO)
    with pytest.raises(ConfigurationError, match=r"parameter channels: channels \[1\] selected"):
        source.update_settings(AudioInputSettings(channels="1"))
    assert source.settings.channels == "mean"
    assert source.decode_audio_data(s16(160)).size == 160


def test_when_audio_info_strings_are_megabytes_long_expect_a_short_message():
    with pytest.raises(UnsupportedAudioFormat) as caught:
        audio_input().set_audio_info(1, 16000, "S" * 10_000_000, "wave")
    assert len(str(caught.value)) < 200
    assert "(10000002 characters)" in str(caught.value)


@pytest.mark.parametrize("dropped_by", ["not whole frames", "max_chunk_s"])
def test_when_a_new_audio_buffer_format_comes_in_a_dropped_message_expect_the_next_flagged(
    dropped_by,
):
    """What follows the decoder (features, voice detection) restarts with the new format."""
    source = AudioInput(AudioInputSettings(input_type="naoqi", max_chunk_s=0.1))
    assert source.decode_audio_buffer(48000, PEPPER_MAP, [0] * 400)[1] is True
    bad = [0] * 401 if dropped_by == "not whole frames" else [0] * (2 * 16000)  # 1 s > 0.1 s
    with pytest.raises(InputError):
        source.decode_audio_buffer(16000, (0, 2), bad)
    assert source.decode_audio_buffer(16000, (0, 2), [0] * 400)[1] is True
    assert source.decode_audio_buffer(16000, (0, 2), [0] * 400)[1] is False

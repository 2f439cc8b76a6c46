"""Tests of audio2pose_ros.audio.features against python_speech_features 0.6 (seed 003 3.2)."""

from __future__ import annotations

import decimal
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from audio2pose_ros.audio.dsp import (
    dct_matrix,
    delta,
    hz_to_mel,
    mel_filterbank,
    mel_to_hz,
    round_half_up,
)
from audio2pose_ros.audio.features import FeatureSpec, extract_features
from audio2pose_ros.audio.normalize import FeatureNormalizer
from audio2pose_ros.audio.pcm import PcmDecoder, PcmFormat, encode_pcm
from audio2pose_ros.audio.streaming import StreamingFeatureExtractor
from audio2pose_ros.audio.wav import read_wav
from audio2pose_ros.errors import ConfigurationError, InputError
from audio2pose_ros.resources import bundled_speech_path

psf = pytest.importorskip("python_speech_features")

SPEECH_WAV = bundled_speech_path("librivox_sense_and_sensibility_01_0880.wav")  # 3 s, S16LE
PRESETS = ["logfb26", "mfcc13", "logfb52", "logfb78"]
S16 = PcmFormat("S16LE", 1, 16000)


def reference(signal: np.ndarray, preset: str) -> np.ndarray:
    """python_speech_features with the seed's settings (seed 003 section 4.2.2)."""
    x = np.asarray(signal, dtype=np.float64)
    common = {"samplerate": 16000, "winlen": 0.025, "winstep": 0.01, "nfilt": 26, "nfft": 512}
    if preset == "mfcc13":
        return psf.mfcc(x, numcep=13, preemph=0.97, ceplifter=22, appendEnergy=True, **common)
    feats = [psf.logfbank(x, preemph=0.97, **common)]
    for _ in range({"logfb26": 0, "logfb52": 1, "logfb78": 2}[preset]):
        feats.append(psf.delta(feats[-1], 2))
    return np.hstack(feats)


@pytest.fixture(scope="module")
def speech() -> np.ndarray:
    """2.99 s of real read speech (bundled LibriVox clip), float32 at 16 kHz."""
    return read_wav(SPEECH_WAV)[0]


def stream_bytes(payload: bytes, spec: FeatureSpec, sizes: list[int]) -> np.ndarray:
    """S16LE bytes -> PcmDecoder -> StreamingFeatureExtractor, in pieces of ``sizes`` (cycled)."""
    decoder, extractor = PcmDecoder(S16), StreamingFeatureExtractor(spec)
    out, i, j = [], 0, 0
    while i < len(payload):
        size = sizes[j % len(sizes)]
        out.append(extractor.push(decoder.feed(payload[i : i + size])))
        i, j = i + size, j + 1
    out.append(extractor.push(decoder.flush()))
    out.append(extractor.flush())
    assert all(o.ndim == 2 and o.shape[1] == spec.dim for o in out)
    return np.vstack(out)


def stream_samples(signal: np.ndarray, spec: FeatureSpec, sizes: list[int]) -> np.ndarray:
    extractor = StreamingFeatureExtractor(spec)
    out, i, j = [], 0, 0
    while i < signal.size:
        out.append(extractor.push(signal[i : i + sizes[j % len(sizes)]]))
        i, j = i + sizes[j % len(sizes)], j + 1
    out.append(extractor.flush())
    return np.vstack(out)


# --- hand-computed small cases ------------------------------------------------------------


def test_when_tiny_config_expect_hand_computed_mel_filterbank():
    # edges 0, 921.5, 3056.0, 8000 Hz -> bins floor(9 f / 16000) = 0, 0, 1, 4
    expected = np.array([[1.0, 0, 0, 0, 0], [0, 1.0, 2 / 3, 1 / 3, 0]])
    np.testing.assert_allclose(mel_filterbank(2, 8, 16000), expected, rtol=0, atol=1e-15)


@pytest.mark.parametrize(
    ("nfilt", "nfft", "rate", "low", "high"),
    [
        (26, 512, 16000, 0, None),
        (40, 512, 16000, 64, 7600),
        (26, 1024, 44100, 0, None),
        (20, 256, 8000, 300, 3400),
        (80, 2048, 48000, 0, None),
        (3, 16, 16000, 0, None),
        (26, 401, 16000, 0, None),  # top edge lands exactly on bin 201: floor() is fragile
    ],
)
def test_when_filterbank_compared_with_python_speech_features_expect_identical(
    nfilt, nfft, rate, low, high
):
    ours = mel_filterbank(nfilt, nfft, rate, low, high)
    np.testing.assert_array_equal(ours, psf.get_filterbanks(nfilt, nfft, rate, low, high))


def test_when_hz_to_mel_expect_seed_eq_3_4_and_inverse():
    assert hz_to_mel(700.0) == pytest.approx(1125.0 * np.log(2.0), rel=1e-15)
    freqs = np.array([0.0, 100.0, 1000.0, 8000.0])
    np.testing.assert_allclose(mel_to_hz(hz_to_mel(freqs)), freqs, rtol=1e-12, atol=1e-9)
    # python_speech_features' 2595 log10 is the same curve with 1127.01 instead of 1125
    np.testing.assert_allclose(
        psf.hz2mel(freqs[1:]) / hz_to_mel(freqs[1:]), 2595 / np.log(10) / 1125.0, rtol=1e-12
    )


def test_when_dct_matrix_expect_scipy_orthonormal_dct_ii():
    from scipy.fftpack import dct

    x = np.random.default_rng(0).standard_normal((5, 26))
    np.testing.assert_allclose(
        x @ dct_matrix(26, 13), dct(x, type=2, norm="ortho")[:, :13], rtol=0, atol=1e-12
    )


def test_when_delta_of_ramp_expect_hand_computed_edge_values():
    ramp = np.arange(5.0)[:, None]
    # padded edges repeat frames 0 and 4, e.g. t=0: (1*1 + 2*2 - 0) / 10 = 0.5
    np.testing.assert_allclose(delta(ramp, 2)[:, 0], [0.5, 0.8, 1.0, 0.8, 0.5], atol=1e-15)
    np.testing.assert_allclose(delta(ramp, 2), psf.delta(ramp, 2), atol=1e-15)


@pytest.mark.parametrize(
    ("n_samples", "n_frames"), [(1, 1), (399, 1), (400, 1), (401, 2), (560, 2), (561, 3), (1000, 5)]
)
def test_when_signal_length_given_expect_python_speech_features_frame_count(n_samples, n_frames):
    signal = np.random.default_rng(n_samples).uniform(-0.5, 0.5, n_samples)
    assert FeatureSpec().n_frames(n_samples) == n_frames
    for preset in PRESETS:
        ours = extract_features(signal, FeatureSpec.preset(preset))
        assert ours.shape == reference(signal, preset).shape == (n_frames, ours.shape[1])
        streamed = stream_samples(signal, FeatureSpec.preset(preset), [160])
        assert streamed.shape == ours.shape


def test_when_digital_silence_expect_log_of_float64_eps():
    out = extract_features(np.zeros(1000))
    np.testing.assert_array_equal(out, np.full((5, 26), np.log(np.finfo(np.float64).eps)))
    np.testing.assert_array_equal(stream_samples(np.zeros(1000), FeatureSpec(), [160]), out)


def test_when_empty_signal_expect_no_frames():
    assert extract_features(np.zeros(0)).shape == (0, 26)
    extractor = StreamingFeatureExtractor(FeatureSpec.preset("logfb78"))
    assert extractor.push(np.zeros(0)).shape == (0, 78)
    assert extractor.flush().shape == (0, 78)


# --- python_speech_features on real speech ------------------------------------------------


@pytest.mark.parametrize("preset", PRESETS)
def test_when_offline_features_of_speech_expect_python_speech_features_values(speech, preset):
    expected = reference(speech, preset)
    ours = extract_features(speech, FeatureSpec.preset(preset))
    assert ours.shape == expected.shape
    np.testing.assert_allclose(ours, expected, rtol=0, atol=1e-4)


@pytest.mark.parametrize("preset", PRESETS)
@pytest.mark.parametrize("chunking", ["odd_bytes", "one_second"])
def test_when_speech_bytes_streamed_in_chunks_expect_python_speech_features_values(
    speech, preset, chunking
):
    payload = encode_pcm(speech, S16)
    assert np.array_equal(PcmDecoder(S16).feed(payload), speech)  # S16 round trip is exact
    if chunking == "odd_bytes":
        sizes = [int(2 * k + 1) for k in np.random.default_rng(11).integers(0, 700, size=400)]
    else:
        sizes = [32000]
    spec = FeatureSpec.preset(preset)
    streamed = stream_bytes(payload, spec, sizes)
    expected = reference(speech, preset)
    assert streamed.shape == expected.shape
    np.testing.assert_allclose(streamed, expected, rtol=0, atol=1e-4)
    np.testing.assert_allclose(streamed, extract_features(speech, spec), rtol=0, atol=1e-9)


@pytest.mark.parametrize("preset", PRESETS)
def test_when_speech_bytes_streamed_one_byte_at_a_time_expect_python_speech_features_values(
    speech, preset
):
    excerpt = speech[8000:16123]  # about 0.5 s of speech, ends in a partial frame
    streamed = stream_bytes(encode_pcm(excerpt, S16), FeatureSpec.preset(preset), [1])
    expected = reference(excerpt, preset)
    assert streamed.shape == expected.shape
    np.testing.assert_allclose(streamed, expected, rtol=0, atol=1e-4)


def test_when_hamming_window_expect_python_speech_features_fbank_with_numpy_hamming(speech):
    spec = FeatureSpec(window="hamming")
    fbank, _ = psf.fbank(speech.astype(np.float64), winfunc=np.hamming)
    np.testing.assert_allclose(extract_features(speech, spec), np.log(fbank), rtol=0, atol=1e-4)
    np.testing.assert_allclose(stream_samples(speech, spec, [160]), np.log(fbank), atol=1e-4)


@settings(max_examples=25, deadline=None)
@given(
    n_samples=st.integers(min_value=1, max_value=3000),
    sizes=st.lists(st.integers(min_value=1, max_value=900), min_size=1, max_size=12),
    preset=st.sampled_from(PRESETS),
    seed=st.integers(min_value=0, max_value=2**16),
)
def test_when_streamed_in_any_chunking_expect_offline_features(n_samples, sizes, preset, seed):
    signal = np.random.default_rng(seed).uniform(-0.5, 0.5, n_samples)
    spec = FeatureSpec.preset(preset)
    np.testing.assert_allclose(
        stream_samples(signal, spec, sizes), extract_features(signal, spec), rtol=0, atol=1e-9
    )


# --- streaming behaviour ------------------------------------------------------------------


@pytest.mark.parametrize(("preset", "lookahead"), [("logfb26", 0), ("logfb52", 2), ("logfb78", 4)])
def test_when_pushing_one_step_at_a_time_expect_frames_after_delta_lookahead(preset, lookahead):
    extractor = StreamingFeatureExtractor(FeatureSpec.preset(preset))
    signal = np.random.default_rng(1).uniform(-0.5, 0.5, 400 + 160 * 19)  # exactly 20 frames
    counts = [extractor.push(signal[:400]).shape[0]]
    counts += [extractor.push(signal[i : i + 160]).shape[0] for i in range(400, signal.size, 160)]
    assert sum(counts) == extractor.frames_emitted == 20 - lookahead
    assert counts[: lookahead + 1] == [0] * lookahead + [1]
    assert extractor.flush().shape[0] == lookahead
    assert extractor.frames_emitted == 0  # flush starts a new stream


def test_when_flushed_expect_new_stream_with_same_output():
    extractor = StreamingFeatureExtractor(FeatureSpec.preset("logfb78"))
    signal = np.random.default_rng(2).uniform(-0.5, 0.5, 2345)
    first = np.vstack([extractor.push(signal), extractor.flush()])
    second = np.vstack([extractor.push(signal), extractor.flush()])
    np.testing.assert_array_equal(first, second)
    assert extractor.frames_per_second == 100.0


def test_when_float32_samples_pushed_expect_same_as_float64():
    signal = np.random.default_rng(4).uniform(-0.5, 0.5, 1600).astype(np.float32)
    spec = FeatureSpec.preset("mfcc13")
    np.testing.assert_array_equal(
        stream_samples(signal, spec, [160]), stream_samples(signal.astype(np.float64), spec, [160])
    )


# --- FeatureSpec ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("preset", "dim", "lookahead"),
    [
        ("logfb26", 26, 0),
        ("logfb52", 52, 2),
        ("logfb78", 78, 4),
        ("mfcc13", 13, 0),
        ("LogFB-78", 78, 4),
    ],
)
def test_when_preset_expect_seed_dimensions(preset, dim, lookahead):
    spec = FeatureSpec.preset(preset)
    assert (spec.dim, spec.lookahead_frames, spec.frame_len, spec.frame_step) == (
        dim,
        lookahead,
        400,
        160,
    )


def test_when_window_is_half_a_sample_expect_round_half_up():
    assert FeatureSpec(window_s=0.02503125).frame_len == 401  # 400.5 samples; round() gives 400


def test_when_rounding_any_float_expect_what_decimal_half_up_gives():
    """round_half_up rounds the exact binary value, as decimal's ROUND_HALF_UP does."""
    halves = np.arange(0, 4000) + 0.5
    values = np.concatenate(
        [
            halves,
            np.nextafter(halves, 0.0),
            np.nextafter(halves, np.inf),
            np.random.default_rng(0).uniform(0.0, 1e6, 2000),
            [0.0, 0.49999999999999994, 0.025 * 16000, 0.01 * 16000, 2.0**52 + 1.0, 1e20],
        ]
    )
    for value in [*values, *(-values)]:
        exact = decimal.Decimal(float(value)).quantize(
            decimal.Decimal(1), rounding=decimal.ROUND_HALF_UP
        )
        assert round_half_up(float(value)) == int(exact), value


def test_when_spec_through_json_expect_equal_spec():
    spec = FeatureSpec(kind="mfcc", delta_order=1, highfreq_hz=7600.0, window="hamming")
    assert FeatureSpec.from_dict(json.loads(json.dumps(spec.to_dict()))) == spec


def test_when_from_dict_has_unknown_key_expect_error_naming_it():
    with pytest.raises(ConfigurationError, match=r"unknown FeatureSpec key\(s\) \['winlen'\]"):
        FeatureSpec.from_dict({"winlen": 0.025})


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"kind": "plp"}, "kind"),
        ({"delta_order": 3}, "delta_order"),
        ({"nfft": 256}, "nfft"),
        ({"highfreq_hz": 9000.0}, "highfreq_hz"),
        ({"kind": "mfcc", "numcep": 30}, "numcep"),
        ({"window": "hann"}, "window"),
        ({"nfilt": 2.5}, "nfilt"),
        # what a hand-made checkpoint header could ask the features node for
        ({"window_s": float("inf")}, "window_s must be a finite number"),
        ({"window_s": float("nan")}, "window_s must be a finite number"),
        ({"step_s": 1e-300}, "cover at least one sample"),
        ({"window_s": 1e6, "nfft": 1 << 40}, "nfft must be an integer in"),
        ({"nfilt": 10**9}, "nfilt must be an integer in"),
        ({"sample_rate_hz": 1}, "sample_rate_hz must be an integer in"),
        ({"sample_rate_hz": 10**12}, "sample_rate_hz must be an integer in"),
        ({"delta_n": 10**9}, "delta_n must be an integer in"),
        ({"ceplifter": float("nan")}, "ceplifter must be a finite number"),
        ({"lowfreq_hz": float("nan")}, "lowfreq_hz must be a finite number"),
        ({"highfreq_hz": "8000"}, "highfreq_hz must be a finite number"),
        ({"append_energy": "yes"}, "append_energy must be true or false"),
        ({"preemph": float("nan")}, "preemph must be a finite number"),
    ],
)
def test_when_spec_invalid_expect_configuration_error_naming_the_field(kwargs, match):
    with pytest.raises(ConfigurationError, match=match) as caught:
        FeatureSpec(**kwargs)
    assert not isinstance(caught.value, ValueError)


def test_when_unknown_preset_expect_error_listing_presets():
    with pytest.raises(ConfigurationError, match="logfb26"):
        FeatureSpec.preset("fbank40")


# --- FeatureNormalizer ----------------------------------------------------------------------


def test_when_normalizer_fitted_expect_zero_mean_unit_std():
    frames = np.random.default_rng(0).normal(3.0, 2.0, size=(500, 26))
    norm = FeatureNormalizer.fit(frames)
    out = norm.apply(frames)
    np.testing.assert_allclose(out.mean(axis=0), 0.0, atol=1e-12)
    np.testing.assert_allclose(out.std(axis=0), 1.0, atol=1e-12)


def test_when_feature_constant_expect_std_floor_and_finite_output():
    frames = np.random.default_rng(1).normal(size=(50, 3))
    frames[:, 1] = np.log(np.finfo(np.float64).eps)  # a band that is digital silence throughout
    norm = FeatureNormalizer.fit(frames)
    assert norm.std[1] == FeatureNormalizer.STD_FLOOR
    out = norm.apply(frames)
    assert np.isfinite(out).all()
    np.testing.assert_allclose(out[:, 1], 0.0, atol=1e-6)  # rounding of the mean / floor


def test_when_normalizer_through_json_expect_same_output():
    frames = np.random.default_rng(2).normal(size=(40, 4))
    norm = FeatureNormalizer.fit(frames)
    again = FeatureNormalizer.from_dict(json.loads(json.dumps(norm.to_dict())))
    np.testing.assert_array_equal(again.apply(frames), norm.apply(frames))


def test_when_normalizer_dict_or_frames_malformed_expect_typed_errors():
    with pytest.raises(ConfigurationError, match=r"exactly the keys \['mean', 'std'\]"):
        FeatureNormalizer.from_dict({"mean": [0.0], "std": [1.0], "var": [1.0]})
    with pytest.raises(ConfigurationError, match="std must be > 0"):
        FeatureNormalizer.from_dict({"mean": [0.0], "std": [0.0]})
    with pytest.raises(InputError, match="non-finite"):
        FeatureNormalizer.fit(np.array([[0.0, np.nan]]))
    with pytest.raises(ValueError, match="dimension 2"):
        FeatureNormalizer(mean=np.zeros(2), std=np.ones(2)).apply(np.zeros((3, 26)))


@pytest.mark.parametrize("use_numpy_rfft", [False, True])
@pytest.mark.parametrize("nfft", [512, 401])
def test_when_fft_path_or_odd_nfft_varies_expect_python_speech_features_values(
    speech, use_numpy_rfft, nfft
):
    spec = FeatureSpec(kind="mfcc", nfft=nfft, delta_order=1)
    extractor = StreamingFeatureExtractor(spec)
    if use_numpy_rfft:
        extractor._kernel.rfft = None  # the public np.fft.rfft fallback of the one-frame path
    excerpt = speech[:8123]
    streamed = [extractor.push(excerpt[i : i + 160]) for i in range(0, excerpt.size, 160)]
    streamed = np.vstack([*streamed, extractor.flush()])
    mfcc = psf.mfcc(excerpt.astype(np.float64), nfft=nfft)
    np.testing.assert_allclose(streamed, np.hstack([mfcc, psf.delta(mfcc, 2)]), atol=1e-4)

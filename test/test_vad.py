"""Energy voice activity detection: speech is active, silence and steady noise are not."""

import numpy as np

from audio2pose_ros.audio.vad import EnergyVad, VadSettings


def states(vad: EnergyVad, signal: np.ndarray, chunk: int = 320) -> np.ndarray:
    return np.array([vad.push(signal[i : i + chunk]) for i in range(0, len(signal), chunk)])


def test_when_real_speech_then_silence_expect_active_then_inactive_after_hangover(speech):
    vad = EnergyVad(VadSettings(hangover_s=0.3))
    signal = np.concatenate([speech, np.zeros(16000, dtype=np.float32)])
    active = states(vad, signal)
    speech_chunks = len(speech) // 320
    assert active[:speech_chunks].mean() > 0.7  # read speech is mostly voiced or in hangover
    assert not active[-20:].any()  # 1 s of silence: inactive well before the end
    assert vad.active is False


def test_when_steady_background_noise_expect_inactive_after_floor_adapts():
    rng = np.random.default_rng(0)
    noise = (0.01 * rng.standard_normal(16000 * 5)).astype(np.float32)  # -40 dBFS hiss
    vad = EnergyVad()
    active = states(vad, noise)
    # The floor climbs 6 dB/s from -62 dBFS: by 4 s it sits at the hiss and nothing is voice.
    assert not active[-len(active) // 5 :].any()


def test_when_odd_chunk_sizes_expect_same_states_as_whole(speech):
    whole = EnergyVad()
    whole.push(speech)
    chunked = EnergyVad()
    for i in range(0, len(speech), 77):
        chunked.push(speech[i : i + 77])
    assert chunked.active == whole.active
    assert chunked.noise_floor_dbfs == whole.noise_floor_dbfs


def test_when_nan_and_inf_samples_pushed_expect_finite_floor_and_speech_still_detected(speech):
    vad = EnergyVad()
    vad.push(np.array([np.nan, np.inf, -np.inf] * 1000))
    assert np.isfinite(vad.noise_floor_dbfs)
    assert states(vad, speech).mean() > 0.5


def test_when_pushed_hop_by_hop_expect_every_state_as_in_pieces(speech):
    """The one-hop path (the node's real-time case) tracks exactly what the general one does."""
    by_hop, in_pieces = EnergyVad(), EnergyVad()
    hops = speech[: 300 * 160].reshape(300, 160)
    for k, hop in enumerate(hops):
        by_hop.push(hop)
        in_pieces.push(hop[:70])
        in_pieces.push(hop[70:])
        assert (by_hop.active, by_hop.noise_floor_dbfs) == (
            in_pieces.active,
            in_pieces.noise_floor_dbfs,
        ), f"hop {k}"
    assert by_hop._hops_since_loud == in_pieces._hops_since_loud

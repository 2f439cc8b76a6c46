"""The operator's voice as NAOqi's ALAudioDevice takes it: 16-bit interleaved stereo blocks.

``ALAudioDevice.sendRemoteBufferToOutput(nframes, buffer)`` plays ``nframes`` frames of 16-bit
interleaved stereo, at most :data:`MAX_FRAMES_PER_CALL` (16384) frames a call, at the output
rate set with ``setParameter("outputSampleRate", rate)``, one of :data:`OUTPUT_RATES_HZ`. The
mono voice is copied to both channels. The robot's microphones' format (naoqi_driver's
AudioBuffer) is here too. This module does not import rclpy or qi.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

__all__ = [
    "BYTES_PER_FRAME",
    "MAX_FRAMES_PER_CALL",
    "MIC_CHANNELS",
    "MIC_FRAMES",
    "MIC_RATE_HZ",
    "OUTPUT_RATES_HZ",
    "check_output_rate",
    "stereo_blocks",
    "stereo_pcm",
]

MAX_FRAMES_PER_CALL = 16384  # ALAudioDevice.sendRemoteBufferToOutput: frames a call, at most
OUTPUT_RATES_HZ = (16000, 22050, 44100, 48000)  # ALAudioDevice's outputSampleRate values
CHANNELS = 2  # interleaved stereo
BYTES_PER_FRAME = CHANNELS * 2  # int16 per channel
# The robot's microphones as naoqi_driver publishes them (naoqi_bridge_msgs/AudioBuffer):
MIC_RATE_HZ = 48000  # 48 kHz ...
MIC_CHANNELS = 4  # ... 4 interleaved int16 channels ...
MIC_FRAMES = 8192  # ... about 170 ms a message


def check_output_rate(rate_hz: int) -> int:
    """``rate_hz`` if ALAudioDevice plays it.

    Raises:
        ValueError: the rate is none of :data:`OUTPUT_RATES_HZ`.
    """
    if rate_hz not in OUTPUT_RATES_HZ:
        raise ValueError(
            f"output rate {rate_hz} Hz: ALAudioDevice plays {', '.join(map(str, OUTPUT_RATES_HZ))}"
        )
    return int(rate_hz)


def stereo_pcm(mono: np.ndarray) -> bytes:
    """Mono float samples in [-1, 1] as 16-bit little-endian interleaved stereo bytes.

    Samples beyond full scale are clipped; a non-finite sample is silence (0), never noise.
    """
    samples = np.nan_to_num(np.asarray(mono, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    pcm = np.clip(np.round(samples * 32767.0), -32768, 32767).astype("<i2")
    return np.repeat(pcm, CHANNELS).tobytes()


def stereo_blocks(mono: np.ndarray) -> Iterator[tuple[int, bytes]]:
    """``(nframes, buffer)`` calls for ``mono``: each at most :data:`MAX_FRAMES_PER_CALL` frames."""
    for start in range(0, len(mono), MAX_FRAMES_PER_CALL):
        block = mono[start : start + MAX_FRAMES_PER_CALL]
        yield len(block), stereo_pcm(block)

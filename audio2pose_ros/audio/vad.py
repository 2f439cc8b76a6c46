"""Energy-based voice activity detection on 10 ms hops, with an adaptive noise floor.

The motion filter returns the robot to its neutral pose when the operator stops speaking; it
learns that from this detector. A hop is loud when its level exceeds both an absolute floor and
the tracked noise floor by a margin; the voice counts as active from the first loud hop until
``hangover_s`` after the last one, so pauses between words do not flicker the state.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from audio2pose_ros.timebase import SAMPLE_RATE_HZ, SAMPLES_PER_FRAME

_EPS = 1e-12  # keeps log10 finite on digital silence


@dataclass(frozen=True)
class VadSettings:
    """Thresholds of :class:`EnergyVad` (levels in dB relative to full scale)."""

    min_level_dbfs: float = -50.0  # quieter hops are never voice
    margin_db: float = 12.0  # voice is this much louder than the noise floor
    floor_rise_db_per_s: float = 6.0  # how fast the floor follows rising background noise
    hangover_s: float = 0.3  # stay active this long after the last loud hop


class EnergyVad:
    """Streaming detector: push 16 kHz samples, read :attr:`active`."""

    def __init__(self, settings: VadSettings | None = None) -> None:
        """Start inactive with the noise floor at the absolute minimum level."""
        self.settings = settings or VadSettings()
        self._rise_per_hop = self.settings.floor_rise_db_per_s * SAMPLES_PER_FRAME / SAMPLE_RATE_HZ
        self._hangover_hops = round(self.settings.hangover_s * SAMPLE_RATE_HZ / SAMPLES_PER_FRAME)
        self.reset()

    def reset(self) -> None:
        """Forget the noise floor and any partial hop."""
        self._pending = np.zeros(0, dtype=np.float64)
        self.noise_floor_dbfs = self.settings.min_level_dbfs - self.settings.margin_db
        self._hops_since_loud = self._hangover_hops + 1
        self.active = False

    def push(self, samples: np.ndarray) -> bool:
        """Process samples in [-1, 1]; returns :attr:`active` after the last complete hop.

        NaN counts as silence and other values are clipped to [-1, 1], so that no input can
        leave the noise floor non-finite (the decoder already refuses NaN; this is the VAD's
        own guard for any other caller). One whole hop with nothing pending, the real-time
        case, takes a short path with the same result.
        """
        x = np.asarray(samples, dtype=np.float64)
        if x.size == SAMPLES_PER_FRAME and not self._pending.size and x.ndim == 1:
            clipped = np.clip(x, -1.0, 1.0)
            power = np.add.reduce(clipped * clipped) / SAMPLES_PER_FRAME  # np.mean's sum
            if power == power:  # no NaN: the level of the one hop, as the general path
                self._hop(float(10.0 * np.log10(power + _EPS)))
                self.active = self._hops_since_loud <= self._hangover_hops
                return self.active
        x = np.clip(np.nan_to_num(x, nan=0.0), -1.0, 1.0)
        data = np.concatenate((self._pending, x.reshape(-1)))
        n_hops = data.size // SAMPLES_PER_FRAME
        self._pending = data[n_hops * SAMPLES_PER_FRAME :]
        if n_hops == 0:
            return self.active
        hops = data[: n_hops * SAMPLES_PER_FRAME].reshape(n_hops, SAMPLES_PER_FRAME)
        for level in 10.0 * np.log10(np.mean(hops * hops, axis=1) + _EPS):
            self._hop(float(level))
        self.active = self._hops_since_loud <= self._hangover_hops
        return self.active

    def _hop(self, level: float) -> None:
        """Track the noise floor and the hops since the last loud one, given a hop's level."""
        # The floor drops at once to a quieter hop and rises slowly otherwise.
        self.noise_floor_dbfs = min(level, self.noise_floor_dbfs + self._rise_per_hop)
        threshold = max(
            self.settings.min_level_dbfs, self.noise_floor_dbfs + self.settings.margin_db
        )
        self._hops_since_loud = 0 if level > threshold else self._hops_since_loud + 1

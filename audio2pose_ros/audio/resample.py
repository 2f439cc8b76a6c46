"""Sample-rate conversion to the frame grid's 16 kHz: a streaming polyphase resampler."""

from __future__ import annotations

import functools
import math

import numpy as np

from audio2pose_ros.errors import UnsupportedAudioFormat

MAX_FILTER_TAPS = 1 << 19  # resampling filter coefficients (float64: 4 MiB)


_BLOCK_VALUES = 1 << 20  # input values gathered per vectorised resampler block (8 MiB)


def resampler_taps(in_rate_hz: int, out_rate_hz: int) -> int:
    """Coefficients of :class:`PolyphaseResampler`'s filter for these rates (1 when equal)."""
    g = math.gcd(int(in_rate_hz), int(out_rate_hz))
    up, down = out_rate_hz // g, in_rate_hz // g
    if up == down == 1:
        return 1
    delay = math.ceil(PolyphaseResampler.ZERO_CROSSINGS * max(up, down) / down)
    return 2 * delay * down + 1


@functools.lru_cache(maxsize=8)
def _polyphase_filter(up: int, down: int) -> tuple[int, np.ndarray]:
    """``(delay_samples, poly)`` of the low-pass for ``up / down`` (read-only, cached).

    Cached because a stream whose format flips between a few rates would otherwise design the
    same filter again for every message.
    """
    max_rate = max(up, down)
    delay_samples = math.ceil(PolyphaseResampler.ZERO_CROSSINGS * max_rate / down)
    half_len = delay_samples * down  # group delay in up-rate samples
    taps = np.arange(-half_len, half_len + 1, dtype=np.float64)
    cutoff = PolyphaseResampler.ROLLOFF * 0.5 / max_rate  # cycles per up-rate sample
    h = 2.0 * cutoff * np.sinc(2.0 * cutoff * taps)
    h *= np.kaiser(taps.size, PolyphaseResampler.KAISER_BETA)
    h *= up / h.sum()  # unit DC gain after zero-stuffing by `up`
    n_taps = -(-h.size // up)
    h = np.concatenate([h, np.zeros(n_taps * up - h.size)])
    # poly[p, j] = h[j * up + p], reversed along j so it pairs with ascending input.
    poly = h.reshape(n_taps, up).T[:, ::-1].copy()
    poly.flags.writeable = False
    return delay_samples, poly


class PolyphaseResampler:
    """Streaming rational-ratio resampler (polyphase Kaiser-windowed-sinc FIR, delay-compensated).

    The ratio ``out_rate_hz / in_rate_hz`` is reduced to ``up / down``. A linear-phase low-pass
    of ``2 * delay_samples * down + 1`` taps at the rate ``in_rate_hz * up`` (cut-off 0.96 of the
    lower Nyquist frequency, Kaiser beta 8, about 80 dB stop-band) is applied in polyphase form.
    The output is delay-compensated: output sample ``m`` is the signal at time
    ``m / out_rate_hz``. Because of that an output sample is only produced once the input
    ``delay_samples`` output periods later has arrived; :meth:`flush` produces the tail (input
    beyond the end taken as zeros). Input before the start is taken as zeros.

    A whole signal of ``n`` input samples gives ``ceil(n * up / down)`` output samples from
    :meth:`process` plus :meth:`flush`, independent of how it was chunked (to rounding error).

    Memory: the filter has at most :data:`MAX_FILTER_TAPS` coefficients, and the temporary
    array of a vectorised block holds at most about :data:`_BLOCK_VALUES` values, whatever the
    size of the input.

    Args:
        in_rate_hz: input sample rate (Hz).
        out_rate_hz: output sample rate (Hz).

    Raises:
        UnsupportedAudioFormat: a rate is not positive, or the filter for this ratio would
            have more than :data:`MAX_FILTER_TAPS` coefficients.

    """

    ZERO_CROSSINGS = 32  # sinc zero crossings per side: sets the filter length and transition
    ROLLOFF = 0.96  # cut-off as a fraction of the lower of the two Nyquist frequencies
    KAISER_BETA = 8.0  # about 80 dB stop-band attenuation

    def __init__(self, in_rate_hz: int, out_rate_hz: int) -> None:
        if in_rate_hz <= 0 or out_rate_hz <= 0:
            raise UnsupportedAudioFormat(
                f"rates must be positive, got {in_rate_hz} -> {out_rate_hz} Hz"
            )
        n_taps = resampler_taps(in_rate_hz, out_rate_hz)
        if n_taps > MAX_FILTER_TAPS:
            raise UnsupportedAudioFormat(
                f"unsupported sample_rate {in_rate_hz}: resampling it to {out_rate_hz} Hz needs "
                f"a {n_taps}-tap filter (at most {MAX_FILTER_TAPS}); use a standard rate such as "
                "16000, 44100 or 48000 Hz"
            )
        g = math.gcd(int(in_rate_hz), int(out_rate_hz))
        self.in_rate_hz = int(in_rate_hz)
        self.out_rate_hz = int(out_rate_hz)
        self.up = self.out_rate_hz // g
        self.down = self.in_rate_hz // g
        if self.up == self.down == 1:
            self.delay_samples = 0
            self._poly = np.ones((1, 1))
        else:
            self.delay_samples, self._poly = _polyphase_filter(self.up, self.down)
        self._block = max(1, _BLOCK_VALUES // self.taps_per_phase)
        self.reset()

    @property
    def passthrough(self) -> bool:
        """True when the rates are equal and samples pass unchanged."""
        return self.up == self.down == 1

    @property
    def taps_per_phase(self) -> int:
        """Input samples that each output sample depends on."""
        return int(self._poly.shape[1])

    def reset(self) -> None:
        """Forget all input: the next sample is the start of a new signal."""
        history = self.taps_per_phase - 1
        self._buf = np.zeros(history)  # input samples, zeros before the signal start
        self._offset = -history  # global input index of _buf[0]
        self._n_in = 0  # input samples received
        self._n_out = 0  # output samples produced

    def _n_available(self, n_in: int) -> int:
        """Count the outputs whose newest input is among the first ``n_in`` input samples."""
        return -(-n_in * self.up // self.down) - self.delay_samples

    def _compute(self, m0: int, m1: int) -> np.ndarray:
        """Output samples ``m0 .. m1 - 1`` from the buffered input."""
        out = np.empty(m1 - m0)
        taps = self.taps_per_phase
        lane = np.arange(taps)
        for b0 in range(m0, m1, self._block):
            b1 = min(b0 + self._block, m1)
            k = (np.arange(b0, b1, dtype=np.int64) + self.delay_samples) * self.down
            newest = k // self.up
            phase = k - newest * self.up
            first = newest - (taps - 1) - self._offset
            values = self._buf[first[:, None] + lane[None, :]]
            out[b0 - m0 : b1 - m0] = np.einsum("ij,ij->i", values, self._poly[phase])
        return out

    def _drop_consumed(self) -> None:
        """Discard input no longer needed by the next output sample."""
        k = (self._n_out + self.delay_samples) * self.down
        keep_from = k // self.up - (self.taps_per_phase - 1)
        cut = keep_from - self._offset
        if cut > 0:
            self._buf = self._buf[cut:]
            self._offset += cut

    def process(self, samples: np.ndarray) -> np.ndarray:
        """Resample the next piece of the input.

        Args:
            samples: (n,) input samples at ``in_rate_hz``.

        Returns:
            (k,) float64 output samples at ``out_rate_hz`` that became computable.

        """
        x = np.asarray(samples, dtype=np.float64).reshape(-1)
        if self.passthrough:
            return x.copy()
        if x.size == 0:
            return np.empty(0)
        self._buf = np.concatenate([self._buf, x])
        self._n_in += x.size
        m1 = self._n_available(self._n_in)
        if m1 <= self._n_out:
            return np.empty(0)
        out = self._compute(self._n_out, m1)
        self._n_out = m1
        self._drop_consumed()
        return out

    def flush(self) -> np.ndarray:
        """Produce the remaining output (input after the end taken as zeros) and reset.

        Returns:
            (k,) float64 output samples, so that the total output of the signal is
            ``ceil(n_in * up / down)`` samples.

        """
        if self.passthrough:
            return np.empty(0)
        total = -(-self._n_in * self.up // self.down)
        out = np.empty(0)
        if total > self._n_out:
            newest = ((total - 1 + self.delay_samples) * self.down) // self.up
            missing = newest + 1 - (self._offset + self._buf.size)
            if missing > 0:
                self._buf = np.concatenate([self._buf, np.zeros(missing)])
            out = self._compute(self._n_out, total)
        self.reset()
        return out

"""Streaming features: :func:`~audio2pose_ros.audio.features.extract_features` chunk by chunk.

The online path of seed 003 section 4.4: the features node pushes each decoded audio chunk and
gets the frames that became complete, with the same numbers as the offline extraction.
"""

from __future__ import annotations

import numpy as np

from audio2pose_ros.audio.dsp import delta_rows
from audio2pose_ros.audio.features import FeatureSpec, FrameKernel


class StreamingFeatureExtractor:
    """Incremental feature extraction: push samples, get the frames that became complete.

    The concatenation of all :meth:`push` outputs and the final :meth:`flush` equals
    :func:`~audio2pose_ros.audio.features.extract_features` of the concatenated samples (to
    float64 rounding), whatever the chunking. A frame is computed as soon as its last sample
    arrives; with deltas it is emitted ``spec.lookahead_frames`` frames later, once the future
    frames eq. 3.5 needs exist (the first frames use repeated copies of frame 0, as
    python_speech_features does). :meth:`flush` adds the zero-padded last partial frame and the
    delta tail, then starts a new stream.

    Pushing one frame step (160 samples) at a time costs one FFT and a few small matrix
    products: the filter bank, window, DCT, lifter and delta weights are precomputed, raw
    samples go into a reused buffer and pre-emphasis (eq. 3.1) is applied per frame. An
    instance keeps scratch buffers and is not thread-safe: use one per stream and thread.

    Args:
        spec: settings (default LogFB-26).

    """

    _BUFFER_STEPS = 64  # initial sample buffer: frame_len + 64 steps (grows for big pushes)
    _HISTORY_ROWS = 256  # initial base-frame history for deltas (grows for big pushes)

    def __init__(self, spec: FeatureSpec | None = None) -> None:
        self.spec = FeatureSpec() if spec is None else spec
        self._kernel = FrameKernel(self.spec)
        self._flen = self.spec.frame_len
        self._step = self.spec.frame_step
        self._alpha = float(self.spec.preemph)
        self._lookahead = self.spec.lookahead_frames
        self._empty = np.empty((0, self.spec.dim))
        self._frame = np.empty(self._flen)  # scratch: one pre-emphasised frame
        # Steady-state delta weights: row o applied to base frames t-L..t+L gives order o at t
        # (eq. 3.5; order 2 is eq. 3.5 applied to order 1, i.e. the kernel convolved with
        # itself). Valid only where no edge padding is involved.
        n = self.spec.delta_n
        kernel = np.arange(-n, n + 1, dtype=np.float64) / (
            2.0 * sum(i * i for i in range(1, n + 1))
        )
        width = 2 * self._lookahead + 1
        rows = [np.zeros(width)]
        rows[0][self._lookahead] = 1.0
        level = np.array([1.0])
        for _ in range(self.spec.delta_order):
            level = np.convolve(level, kernel)
            pad = (width - level.size) // 2
            rows.append(np.pad(level, (pad, pad)))
        self._delta_weights = np.vstack(rows)
        self.reset()

    @property
    def frames_per_second(self) -> float:
        """Feature frame rate (Hz, 100 by default)."""
        return self.spec.frames_per_second

    @property
    def frames_emitted(self) -> int:
        """Frames returned since the stream started (the index of the next frame)."""
        return self._emitted

    @property
    def samples_pushed(self) -> int:
        """Samples pushed since the stream started."""
        return self._total

    def reset(self) -> None:
        """Drop all state and start a new stream."""
        self._raw = np.zeros(1 + self._flen + self._BUFFER_STEPS * self._step)  # raw samples
        self._fill = 1  # valid samples in _raw; _raw[0] = 0 is x[-1] of eq. 3.1
        self._start = 1  # _raw index where the next frame starts
        self._total = 0  # samples pushed
        self._n_base = 0  # base frames computed
        self._emitted = 0  # frames returned
        self._hist = np.empty((self._HISTORY_ROWS, self.spec.base_dim))  # base frames (deltas)
        self._hist_len = 0  # valid rows of _hist
        self._hist_start = 0  # global frame index of _hist[0]

    def _make_room(self, n: int) -> int:
        """Move the samples still needed to the buffer front, growing it if needed.

        Returns:
            The new fill level.

        """
        keep = self._raw[self._start - 1 : self._fill]  # x[-1] of the next frame onwards
        size = self._raw.size
        if keep.size + n > size:
            size = 2 * (keep.size + n)
        raw = np.empty(size) if size > self._raw.size else self._raw
        raw[: keep.size] = keep  # overlapping copy is safe: numpy buffers the move
        self._raw = raw
        self._start = 1
        self._fill = keep.size
        return self._fill

    def push(self, samples: np.ndarray) -> np.ndarray:
        """Add samples; return the frames that became complete.

        Args:
            samples: (n,) mono samples at ``spec.sample_rate_hz`` (any float dtype).

        Returns:
            (k, spec.dim) float64 features, k >= 0.

        """
        x = samples
        if not (isinstance(x, np.ndarray) and x.ndim == 1 and x.dtype.kind == "f"):
            x = np.asarray(samples, dtype=np.float64).reshape(-1)
        n = x.size
        if n == 0:
            return self._empty
        fill = self._fill
        if fill + n > self._raw.size:
            fill = self._make_room(n)
        raw = self._raw
        raw[fill : fill + n] = x  # float32 input is widened exactly to float64
        fill += n
        self._fill = fill
        self._total += n
        start = self._start
        flen = self._flen
        available = fill - start - flen
        if available < 0:
            return self._empty
        if available < self._step:  # exactly one new frame: the real-time case
            k = 1
            frame = self._frame
            np.multiply(raw[start - 1 : start - 1 + flen], self._alpha, out=frame)  # eq. 3.1
            np.subtract(raw[start : start + flen], frame, out=frame)
            base = self._kernel.single(frame)
        else:
            k = available // self._step + 1
            stop = start + (k - 1) * self._step + flen
            emphasised = raw[start:stop] - self._alpha * raw[start - 1 : stop - 1]  # eq. 3.1
            view = np.lib.stride_tricks.sliding_window_view(emphasised, flen)
            base = self._kernel(view[:: self._step])
        self._start = start + k * self._step
        self._n_base += k
        if self._lookahead == 0:
            self._emitted += k
            return base
        return self._deltas(base, last=None)

    def flush(self) -> np.ndarray:
        """End the stream: emit the zero-padded last partial frame and the delta tail, then reset.

        Returns:
            (k, spec.dim) float64 features; empty if nothing was pushed.

        """
        base = np.empty((0, self.spec.base_dim))
        if self.spec.n_frames(self._total) > self._n_base:  # at most one partial frame remains
            start, fill = self._start, self._fill
            frame = np.zeros((1, self._flen))
            frame[0, : fill - start] = (
                self._raw[start:fill] - self._alpha * self._raw[start - 1 : fill - 1]
            )
            base = self._kernel(frame)
            self._n_base += 1
        if self._lookahead == 0:
            out = base
        elif self._n_base > 0:
            out = self._deltas(base, last=self._n_base - 1)
        else:
            out = self._empty
        self.reset()
        return out

    def _store(self, base: np.ndarray) -> None:
        """Append base frames to the history, dropping rows no later frame needs."""
        k = base.shape[0]
        if self._hist_len + k > self._hist.shape[0]:
            keep_from = max(0, self._emitted - self._lookahead)  # oldest row still needed
            keep = self._hist[keep_from - self._hist_start : self._hist_len]
            rows = max(self._hist.shape[0], 2 * (keep.shape[0] + k))
            hist = (
                np.empty((rows, self._hist.shape[1])) if rows > self._hist.shape[0] else self._hist
            )
            hist[: keep.shape[0]] = keep
            self._hist = hist
            self._hist_len = keep.shape[0]
            self._hist_start = keep_from
        self._hist[self._hist_len : self._hist_len + k] = base
        self._hist_len += k

    def _deltas(self, base: np.ndarray, last: int | None) -> np.ndarray:
        """Store new base frames and return the frames whose deltas are now computable.

        Args:
            base: the newest base frames (global indices up to ``n_base - 1``).
            last: global index of the stream's last frame at the end of the stream, else None.

        Returns:
            (k, spec.dim) frames: base features followed by the delta orders.

        """
        if base.shape[0]:
            self._store(base)
        lookahead = self._lookahead
        t = self._emitted
        end = self._n_base if last is not None else self._n_base - lookahead
        if end <= t:
            return self._empty
        if last is None and end == t + 1 and t >= lookahead:
            # steady state: one frame, no edge padding -> one small matrix product
            window = self._hist[self._hist_len - 2 * lookahead - 1 : self._hist_len]
            self._emitted = end
            return (self._delta_weights @ window).reshape(1, -1)
        top = self._n_base - 1 if last is None else last
        n = self.spec.delta_n
        rows = np.arange(t, end)
        level, level_start = self._hist[: self._hist_len], self._hist_start
        parts = [level[rows - level_start]]
        for order in range(1, self.spec.delta_order + 1):
            # rows of this order that the higher orders still need (eq. 3.5 applied again)
            reach = n * (self.spec.delta_order - order)
            need = np.arange(max(0, t - reach), min(top, end - 1 + reach) + 1)
            level = delta_rows(level, level_start, need, top, n)
            level_start = int(need[0])
            parts.append(level[rows - level_start])
        self._emitted = end
        return np.hstack(parts)

"""WAV files to 16 kHz mono samples through a bounded RIFF reader."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np

from audio2pose_ros.audio.pcm import PcmDecoder, PcmFormat
from audio2pose_ros.errors import InputError, InvalidAudio, UnsupportedAudioFormat
from audio2pose_ros.timebase import SAMPLE_RATE_HZ

WAV_BLOCK_FRAMES = 1 << 16  # frames decoded per step by read_wav (bounds its temporaries)


_WAVE_FORMAT_PCM = 0x0001


_WAVE_FORMAT_IEEE_FLOAT = 0x0003


_WAVE_FORMAT_EXTENSIBLE = 0xFFFE


@dataclass(frozen=True)
class _WavLayout:
    """The ``fmt `` chunk of a WAV file (fields as the RIFF/WAVE specification names them)."""

    format_tag: int
    channels: int
    sample_rate_hz: int
    block_align: int
    bits_per_sample: int


def _wav_chunks(raw: bytes) -> tuple[_WavLayout, memoryview]:
    """Walk the RIFF chunks of a WAV file held in ``raw``: its ``fmt `` layout and its samples.

    A chunk that claims more bytes than the file holds is cut at the end of the file, so
    nothing larger than the file is ever referenced.

    Raises:
        InvalidAudio: not RIFF/WAVE, or no well-formed ``fmt `` or ``data`` chunk (without
            the path; :func:`read_wav` adds it).

    """
    if len(raw) < 12 or raw[:4] != b"RIFF" or raw[8:12] != b"WAVE":
        raise InvalidAudio(f"not a RIFF/WAVE file ({len(raw)} bytes, starts {raw[:12]!r})")
    view = memoryview(raw)
    layout: _WavLayout | None = None
    data: memoryview | None = None
    pos = 12
    while pos + 8 <= len(raw) and (layout is None or data is None):
        chunk_id, size = raw[pos : pos + 4], struct.unpack_from("<I", raw, pos + 4)[0]
        body = view[pos + 8 : min(pos + 8 + size, len(raw))]
        if chunk_id == b"fmt ":
            if len(body) < 16:
                raise InvalidAudio(f"'fmt ' chunk of {len(body)} bytes (at least 16 needed)")
            tag, channels, rate, _, block_align, bits = struct.unpack_from("<HHIIHH", body)
            if tag == _WAVE_FORMAT_EXTENSIBLE and len(body) >= 26:
                tag = struct.unpack_from("<H", body, 24)[0]  # first field of SubFormat
            layout = _WavLayout(tag, channels, rate, block_align, bits)
        elif chunk_id == b"data":
            data = body
        pos += 8 + size + (size & 1)  # chunks are padded to an even size
    if layout is None:
        raise InvalidAudio("no 'fmt ' chunk")
    if data is None:
        raise InvalidAudio("no 'data' chunk")
    return layout, data


def _wav_samples(layout: _WavLayout, data: memoryview) -> tuple[PcmFormat, np.ndarray]:
    """The PcmFormat of a WAV layout and its (n_frames, channels) samples in that format.

    24-bit samples are left-aligned in int32 (read as S32LE), 64-bit floats become float32.

    Raises:
        UnsupportedAudioFormat: the sample type, channel count or rate is not supported.

    """
    kinds = {
        (_WAVE_FORMAT_PCM, 8): ("U8", "u1"),
        (_WAVE_FORMAT_PCM, 16): ("S16LE", "<i2"),
        (_WAVE_FORMAT_PCM, 24): ("S32LE", "V3"),
        (_WAVE_FORMAT_PCM, 32): ("S32LE", "<i4"),
        (_WAVE_FORMAT_IEEE_FLOAT, 32): ("F32LE", "<f4"),
        (_WAVE_FORMAT_IEEE_FLOAT, 64): ("F32LE", "<f8"),
    }
    kind = kinds.get((layout.format_tag, layout.bits_per_sample))
    if kind is None:
        raise UnsupportedAudioFormat(
            f"unsupported WAV sample type (format tag {layout.format_tag:#06x}, "
            f"{layout.bits_per_sample} bits); supported: 8/16/24/32-bit integer PCM, "
            "32/64-bit float"
        )
    sample_format, stored = kind
    fmt = PcmFormat(sample_format, layout.channels, layout.sample_rate_hz, "wave")
    sample_bytes = np.dtype(stored).itemsize
    if layout.block_align != sample_bytes * layout.channels:
        raise UnsupportedAudioFormat(
            f"block_align {layout.block_align} does not match {layout.channels} channel(s) of "
            f"{layout.bits_per_sample}-bit samples ({sample_bytes * layout.channels} expected)"
        )
    n_frames = len(data) // layout.block_align  # a truncated last frame is dropped
    values = np.frombuffer(data, dtype=stored, count=n_frames * layout.channels)
    if stored == "V3":  # 24-bit: place the three bytes in the top of a little-endian int32
        wide = np.zeros((values.size, 4), dtype=np.uint8)
        wide[:, 1:] = np.frombuffer(values.tobytes(), dtype=np.uint8).reshape(-1, 3)
        values = wide.view("<i4").reshape(-1)
    return fmt, values.astype(fmt.dtype, copy=False).reshape(n_frames, layout.channels)


def read_wav(
    path: str | PathLike[str], target_rate_hz: int = SAMPLE_RATE_HZ
) -> tuple[np.ndarray, int]:
    """Read a WAV file as float32 mono at the target rate (seed 003 section 4.2.2).

    The file is decoded by :class:`PcmDecoder` (same scaling, channel averaging, resampler and
    limits as the streaming path) and flushed, so the result is delay-compensated and has
    ``ceil(n * target_rate_hz / original_rate)`` samples. 8-, 16-, 24- and 32-bit integer and
    32/64-bit float WAVs (WAVE_FORMAT_EXTENSIBLE too) with 1 .. :data:`MAX_CHANNELS` channels
    at :data:`MIN_SAMPLE_RATE_HZ` .. :data:`MAX_SAMPLE_RATE_HZ` are read.

    Memory is bounded by the file's size: the file is read once, chunk sizes that its header
    claims are cut at the end of the file, and the samples are decoded
    :data:`WAV_BLOCK_FRAMES` frames at a time; the result holds at most two float32 samples
    per input frame. Peak use is about three times the file's size plus a few MiB.

    Args:
        path: WAV file.
        target_rate_hz: output sample rate (Hz, default 16000).

    Returns:
        ``(samples, original_rate)``: (n,) float32 samples in [-1, 1) and the file's rate (Hz).

    Raises:
        InputError: the file cannot be read.
        UnsupportedAudioFormat: the WAV's sample type, channel count or rate is not supported.
        InvalidAudio: the file is not a well-formed WAV, holds no samples, or holds NaN or inf.
        Every message starts with the file's path.

    """
    try:
        raw = Path(path).read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: cannot read WAV file: {exc.strerror or exc}") from None
    try:
        fmt, frames = _wav_samples(*_wav_chunks(raw))
        decoder = PcmDecoder(fmt, target_rate_hz)
        if frames.shape[0] == 0:
            raise InvalidAudio("the WAV file holds no samples")
        pieces = [
            decoder.feed(frames[start : start + WAV_BLOCK_FRAMES].tobytes())
            for start in range(0, frames.shape[0], WAV_BLOCK_FRAMES)
        ]
    except InputError as exc:
        raise type(exc)(f"{path}: {exc}") from None
    pieces.append(decoder.flush())
    return np.concatenate(pieces), fmt.sample_rate_hz

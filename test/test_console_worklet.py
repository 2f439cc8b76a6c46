"""The page's microphone resampler (web/src/worklet.js), run by Node.js outside a browser.

Whatever rate the browser's microphone runs at, the page must send 16 kHz mono signed 16-bit
chunks of 20 ms, keep the speech band and not fold anything above 8 kHz into it. Skipped where
node is not installed.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
WORKLET = ROOT / "web" / "src" / "worklet.js"
HARNESS = Path(__file__).with_name("console_worklet_harness.mjs")

pytestmark = pytest.mark.skipif(shutil.which("node") is None, reason="node is not installed")


def resampled(rate_hz: int, tone_hz: float) -> tuple[list[int], np.ndarray]:
    """Chunk sizes and the 16 kHz signal the worklet makes of a 0.5-amplitude tone."""
    out = subprocess.run(
        ["node", str(HARNESS), str(WORKLET), str(rate_hz), str(tone_hz)],
        check=True,
        capture_output=True,
        text=True,
        timeout=60,
    )
    result = json.loads(out.stdout)
    return result["sizes"], np.array(result["samples"], dtype=np.float64) / 32767.0


@pytest.mark.parametrize("rate_hz", [16000, 44100, 48000])
def test_when_the_microphone_runs_at_any_rate_expect_16k_chunks_of_20_ms_keeping_speech(rate_hz):
    sizes, signal = resampled(rate_hz, 1000.0)
    assert sizes == [320]
    assert len(signal) > 0.95 * 16000  # one second in, about one second out
    spectrum = np.abs(np.fft.rfft(signal * np.hanning(len(signal))))
    assert np.argmax(spectrum) * 16000 / len(signal) == pytest.approx(1000.0, abs=2.0)
    rms = np.sqrt(np.mean(signal[400:] ** 2))
    assert rms == pytest.approx(0.5 / np.sqrt(2), rel=0.01)  # the level is kept


@pytest.mark.parametrize("rate_hz", [44100, 48000])
def test_when_the_microphone_hears_above_8k_expect_nothing_folded_into_the_speech_band(rate_hz):
    _, signal = resampled(rate_hz, 12000.0)  # would alias to 4 kHz without the low-pass
    rms = np.sqrt(np.mean(signal[400:] ** 2))
    assert rms < 0.5 / np.sqrt(2) * 1e-3  # more than 60 dB down

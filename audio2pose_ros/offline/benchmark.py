"""Per-frame cost of the streaming pipeline, measured on real speech (``audio2pose bench``).

Each 10 ms frame of the online path costs: pushing 160 new samples into the streaming feature
extractor, z-normalising the frame, one step of the streaming model, mapping back to radians, and
one step of the motion filter (jitter buffer, smoothing, limits, self-collision guard, the
guard also timed alone). Seed 003 section 5.1.2
reports 10 +- 6 ms for the whole per-frame processing on a laptop; the reference column here is
the seed's own approach to online features: python_speech_features run on the latest 25 ms window
for every frame.

:func:`model_costs` compares the model families: for each registered streaming model the cost
of one ``step`` of its streaming predictor, of the torch-free kernel that ``inference_node``
runs (:mod:`audio2pose_ros.checkpoints.numpy_runtime`) and of one torch call per frame (the
module's ``forward``
on one frame: for the recurrent models the same work as a stateful step), and for every model
the offline throughput of
:func:`~audio2pose_ros.offline.synthesis.synthesize` (features, model, smoothing) in seconds of
audio per
second. Costs do not depend on the weights, so untrained models of the default sizes are timed.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import numpy as np
import torch

from audio2pose_ros.audio.features import FeatureSpec, extract_features
from audio2pose_ros.audio.normalize import FeatureNormalizer
from audio2pose_ros.audio.streaming import StreamingFeatureExtractor
from audio2pose_ros.checkpoints.numpy_runtime import numpy_kernel_for
from audio2pose_ros.checkpoints.torch_io import Checkpoint
from audio2pose_ros.models.registry import MODEL_REGISTRY, build_model
from audio2pose_ros.motion.filter import MotionFilter
from audio2pose_ros.offline.synthesis import synthesize
from audio2pose_ros.robot.description import RobotDescription
from audio2pose_ros.timebase import SAMPLE_RATE_HZ, SAMPLES_PER_FRAME, WINDOW_SAMPLES


@dataclass(frozen=True)
class Timing:
    """Per-call cost in microseconds."""

    name: str
    median_us: float
    p99_us: float
    calls: int

    @classmethod
    def of(cls, name: str, samples_ns: list[int]) -> Timing:
        """Summarise per-call durations in nanoseconds."""
        values = np.asarray(samples_ns, dtype=np.float64) / 1e3
        return cls(name, float(np.median(values)), float(np.percentile(values, 99)), len(values))


def _time_calls(calls: list[Callable[[], object]], period_s: float = 0.0) -> list[int]:
    """Each call's duration (ns); with ``period_s`` > 0 one call per period, as a node runs them.

    Back to back, a stage runs with warm caches; once every 10 ms, as in a node that waits for
    the next message in between, the same work takes about twice as long on the machines we
    measured (the caches hold other work by then), and that is what a node's CPU figure pays.
    """
    durations = []
    next_s = time.monotonic()
    for call in calls:
        start = time.perf_counter_ns()
        call()
        durations.append(time.perf_counter_ns() - start)
        if period_s > 0.0:
            next_s += period_s
            time.sleep(max(0.0, next_s - time.monotonic()))
    return durations


def streaming_costs(
    checkpoint: Checkpoint,
    filt: MotionFilter,
    signal_16k: np.ndarray,
    n_frames: int = 3000,
    period_s: float = 0.0,
) -> list[Timing]:
    """Time each stage and the whole online frame on ``n_frames`` frames of ``signal_16k``.

    The signal is repeated as needed. Stages are timed one call at a time, as the nodes run
    them: back to back, or with ``period_s`` > 0 one call per period (:func:`_time_calls`).
    """
    spec = checkpoint.features
    step = spec.frame_step
    needed = (n_frames + 4) * step + spec.frame_len
    audio = np.resize(np.asarray(signal_16k, dtype=np.float32), needed)
    chunks = [audio[i * step : (i + 1) * step] for i in range(needed // step)]

    extractor = StreamingFeatureExtractor(spec)
    feature_frames: list[np.ndarray] = []
    feature_ns = _time_calls(
        [partial(lambda c: feature_frames.extend(extractor.push(c)), c) for c in chunks],
        period_s,
    )
    frames = np.asarray(feature_frames[:n_frames])
    normalized = checkpoint.normalizer.apply(frames)

    predictor = checkpoint.model.streaming_predictor()
    model_ns = _time_calls([partial(predictor.step, f) for f in normalized], period_s)
    poses = checkpoint.robot.denormalize(np.array([predictor.step(f) for f in normalized]))

    clock = [0.0]

    def filter_step(pose: np.ndarray) -> None:
        clock[0] += filt.period_s
        filt.push(pose[None, :], clock[0])
        filt.tick(clock[0])

    guard_ns: list[int] = []

    def filter_step_and_guard(pose: np.ndarray) -> None:
        filter_step(pose)
        guard_ns.append(filt.body_guard.status.last_cost_ns)

    filter_ns = _time_calls([partial(filter_step_and_guard, p) for p in poses], period_s)

    total_extractor = StreamingFeatureExtractor(spec)
    total_predictor = checkpoint.model.streaming_predictor()

    def whole_frame(chunk: np.ndarray) -> None:
        for frame in total_extractor.push(chunk):
            pose = total_predictor.step(checkpoint.normalizer.apply(frame[None, :])[0])
            filter_step(checkpoint.robot.denormalize(pose))

    total_ns = _time_calls([partial(whole_frame, c) for c in chunks[:n_frames]], period_s)
    return [
        Timing.of("features (push 160 samples)", feature_ns[:n_frames]),
        Timing.of(f"model step ({checkpoint.model.name})", model_ns),
        Timing.of("motion filter (push + tick)", filter_ns),
        Timing.of("  of which the self-collision guard", guard_ns),
        Timing.of("whole online frame", total_ns),
    ]


def reference_feature_cost(
    signal_16k: np.ndarray, n_frames: int = 1000, period_s: float = 0.0
) -> Timing:
    """python_speech_features.logfbank on the latest 25 ms window, once per frame (seed 4.4.2).

    Timed as :func:`streaming_costs` times the stages (``period_s``).
    """
    from python_speech_features import logfbank

    step, window = SAMPLES_PER_FRAME, WINDOW_SAMPLES
    audio = np.resize(np.asarray(signal_16k, dtype=np.float64), (n_frames + 3) * step)
    windows = [audio[i * step : i * step + window] for i in range(n_frames)]
    return Timing.of(
        "python_speech_features.logfbank per 25 ms window",
        _time_calls([partial(logfbank, w, SAMPLE_RATE_HZ, nfft=512) for w in windows], period_s),
    )


@dataclass(frozen=True)
class ModelCost:
    """Cost of one model family.

    Attributes:
        name: registry name.
        step: per-frame cost of the streaming predictor; None for offline-only models.
        offline_audio_s_per_s: seconds of audio synthesised offline per second of compute.
        kernel_step: per-frame cost of the torch-free kernel; None without one.
        torch_step: per-frame cost of a torch call on one frame; None for offline-only models.

    """

    name: str
    step: Timing | None
    offline_audio_s_per_s: float
    kernel_step: Timing | None = None
    torch_step: Timing | None = None


def model_costs(
    signal_16k: np.ndarray, robot: RobotDescription, n_frames: int = 2000, repeats: int = 3
) -> list[ModelCost]:
    """Time every registered model on ``signal_16k`` (run it on one core for stable numbers).

    Args:
        signal_16k: speech at 16 kHz; offline throughput is measured on the whole signal.
        robot: output joints.
        n_frames: streaming steps timed per model (the signal's frames, repeated).
        repeats: offline syntheses per model; the fastest counts.

    Returns:
        One :class:`ModelCost` per registered model, in registry order.

    """
    spec = FeatureSpec()
    raw = extract_features(signal_16k, spec)
    normalizer = FeatureNormalizer.fit(raw)
    frames = np.resize(normalizer.apply(raw), (n_frames, spec.dim))
    audio_s = signal_16k.shape[0] / spec.sample_rate_hz
    costs = []
    for name in MODEL_REGISTRY:
        torch.manual_seed(0)
        model = build_model(name, {"n_features": spec.dim, "n_joints": robot.n_joints}).eval()
        step = kernel_step = torch_step = None
        if model.streaming:
            step_fn = model.streaming_predictor().step
            step = Timing.of(name, _time_calls([partial(step_fn, f) for f in frames]))
            kernel = numpy_kernel_for(name, model.config_dict())
            if kernel is not None:
                tensors = {k: v.detach().numpy() for k, v in model.state_dict().items()}
                run = kernel.build(tensors, model.config_dict()).step
                kernel_step = Timing.of(name, _time_calls([partial(run, f) for f in frames]))
            inputs = torch.from_numpy(frames).float()[:, None, None, :]  # (N, 1, 1, F)
            with torch.no_grad():
                torch_step = Timing.of(name, _time_calls([partial(model, x) for x in inputs]))
        checkpoint = Checkpoint(model, spec, normalizer, robot)
        durations = _time_calls(
            [partial(synthesize, checkpoint, signal_16k) for _ in range(repeats)]
        )
        costs.append(
            ModelCost(name, step, audio_s / (min(durations) / 1e9), kernel_step, torch_step)
        )
    return costs

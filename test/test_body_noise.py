"""Body-aware sampling: the arm part's noise fades as its previous pose nears Pepper's body."""

import pickle
from dataclasses import replace

import numpy as np
import pytest
import torch
from body_poses import AWAY, INSIDE, RIGHT_AWAY, pose_with

from audio2pose_ros.audio.features import extract_features
from audio2pose_ros.audio.wav import read_wav
from audio2pose_ros.checkpoints.numpy_runtime import numpy_kernel_for
from audio2pose_ros.checkpoints.torch_io import Checkpoint, load_checkpoint
from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.models.body_noise import BOUND_SLACK_M, MAX_FACTOR_STEP, BodyNoise
from audio2pose_ros.models.registry import build_model
from audio2pose_ros.offline.synthesis import synthesize_samples
from audio2pose_ros.resources import bundled_speech_paths, default_checkpoint_path
from audio2pose_ros.robot import capsules
from audio2pose_ros.robot.body import BodyModel
from audio2pose_ros.robot.capsules import CapsuleModel


@pytest.fixture(scope="module")
def body(robot):
    return BodyModel.load(robot)


def _faded(clearance, margin_m, band_m):
    """The factors of one sequence: clip((c - margin) / band, 0, 1), at most 0.05 per frame."""
    out, last = [], 1.0
    for wanted in np.clip((np.asarray(clearance) - margin_m) / band_m, 0, 1):
        last = float(np.clip(wanted, last - MAX_FACTOR_STEP, last + MAX_FACTOR_STEP))
        out.append(last)
    return np.array(out)


def _assert_faded(factors, clearance, margin_m, band_m):
    """The factors of a sampler that measures ``clearance`` (the capsules'): taken from a bound
    at most BOUND_SLACK_M below it, so between the fades of the two."""
    factors = np.asarray(factors)
    assert np.all(factors <= _faded(clearance, margin_m, band_m) + 1e-9)
    assert np.all(factors >= _faded(np.asarray(clearance) - BOUND_SLACK_M, margin_m, band_m) - 1e-9)


def _track(robot, n, shape=lambda x: x):
    """n poses of the left arm from away from the body into the torso (right arm away)."""
    away, inside = (pose_with(robot, **pose, **RIGHT_AWAY) for pose in (AWAY, INSIDE))
    return away + shape(np.linspace(0, 1, n))[:, None] * (inside - away)


def test_when_a_pose_nears_the_body_expect_its_noise_to_fade_to_nothing_at_the_margin(robot, body):
    noise = BodyNoise(robot, margin_m=0.02, band_m=0.03)
    track = _track(robot, 120)
    exact = body.clearance(track)
    assert exact[0] > 0.06
    assert exact[-1] < 0.0
    clearance = noise.body.clearance(track)  # the capsules': at most 2.3 cm below, near the body
    assert np.all(clearance <= np.maximum(exact, 0.0) + 1e-6)
    factors = np.array([noise.factors(robot.normalize(p))[0] for p in track])
    _assert_faded(factors, clearance, 0.02, 0.03)
    assert factors[0] == 1.0
    assert factors[-1] == 0.0
    assert np.abs(np.diff(factors)).max() <= MAX_FACTOR_STEP + 1e-12  # a fade, never a jump
    assert 0 < factors[(clearance > 0.025) & (clearance < 0.045)].min() < 1
    restored = pickle.loads(pickle.dumps(noise))  # workers receive models that hold it
    np.testing.assert_allclose(restored.factors(robot.normalize(track[-1])), [0.0], atol=1e-4)
    restored.reset()
    assert restored.factors(robot.normalize(track[-1]))[0] == 1 - MAX_FACTOR_STEP  # fades anew


def test_when_sequences_run_side_by_side_expect_each_its_own_fade(robot):
    """Row i of every call continues sequence i, as the batch sampler calls it."""
    track = _track(robot, 60)
    both = BodyNoise(robot, 0.02, 0.03)
    rows = [both.factors(robot.normalize(np.stack([p, track[0]]))) for p in track]
    clearance = both.body.clearance(track)
    _assert_faded([r[0] for r in rows], clearance, 0.02, 0.03)
    np.testing.assert_allclose([r[1] for r in rows], _faded(clearance[:1].repeat(60), 0.02, 0.03))


def test_when_a_previous_pose_is_not_finite_expect_a_clear_error(robot):
    """A NaN would pass the travel bound unseen (every comparison with it is false)."""
    noise = BodyNoise(robot, 0.02, 0.03)
    away = robot.normalize(pose_with(robot, **AWAY, **RIGHT_AWAY))
    noise.factors(away)
    for bad in (np.nan, np.inf):
        pose = away.copy()
        pose[robot.names.index("LElbowRoll")] = bad
        with pytest.raises(ValueError, match="not finite"):
            noise.factors(pose)
    assert noise.factors(away)[0] == 1.0  # the sequence goes on


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("body_band_m", -0.01),
        ("body_band_m", float("nan")),
        ("body_band_m", 0.6),
        ("body_margin_m", -0.1),
        ("body_margin_m", float("inf")),
    ],
)
def test_when_a_body_setting_is_out_of_range_expect_a_configuration_error_and_no_kernel(key, value):
    with pytest.raises(ConfigurationError, match=r"body_|not finite"):
        build_model("live_groups", {"n_features": 4, "n_joints": 11, key: value})
    config = build_model("live_groups", {"n_features": 4, "n_joints": 11}).config_dict()
    assert "body_band_m" not in config  # off: checkpoints keep the keys they always had
    assert numpy_kernel_for("live_groups", {**config, key: value}) is None
    assert numpy_kernel_for("live_groups", {**config, "body_band_m": 0.05}) is not None


def test_when_a_model_samples_with_the_body_in_mind_expect_batch_and_stream_alike(robot):
    torch.manual_seed(0)
    model = build_model(
        "live_groups",
        {"n_features": 4, "n_joints": 11, "body_margin_m": 0.0, "body_band_m": 0.5},
    )
    features = torch.randn(1, 120, 4)
    unbound = model.sample(features, 1, torch.Generator().manual_seed(2))
    assert model.body_noise() == (None, -1)  # no robot, no body
    model.bind_robot(robot)
    noise, part = model.body_noise()
    assert noise is not None
    assert part == 1  # the arms' part
    batch = model.sample(features, 1, torch.Generator().manual_seed(2))[0, 0].double().numpy()
    head = robot.group_mask("head")
    np.testing.assert_allclose(batch[:, head], unbound[0, 0][:, head].numpy())  # head untouched
    assert np.abs(batch[:, ~head] - unbound[0, 0][:, ~head].numpy()).max() > 1e-3
    predictor = model.streaming_predictor(seed=2)
    stream = np.array([predictor.step(f) for f in features[0].double().numpy()])
    np.testing.assert_allclose(stream, batch, atol=1e-5)
    predictor.reset()
    np.testing.assert_allclose(
        [predictor.step(f) for f in features[0, :30].double().numpy()], batch[:30], atol=1e-5
    )


def test_when_a_checkpoint_holds_the_model_expect_it_bound_to_the_checkpoint_robot(robot):
    loaded = load_checkpoint(default_checkpoint_path(), robot=robot)
    fresh = build_model("live_groups", {"n_joints": 11, "body_band_m": 0.05})
    assert fresh.body_noise() == (None, -1)
    held = replace(loaded, model=fresh)
    assert isinstance(held, Checkpoint)
    assert held.model.body_noise()[0] is not None
    tuned = held.model.with_sampling(second_temperature=2.0)  # copies keep the robot
    assert tuned.body_noise()[0] is not None
    assert pickle.loads(pickle.dumps(tuned)).body_noise()[0] is not None


def test_when_the_default_model_speaks_new_voices_expect_its_arms_rarely_near_the_body(robot, body):
    """Without the body in mind, the noise of a sample can drift onto the torso and stay; with
    it, the model's arms come within the margin in under 1 % of frames, and never more often
    than without (the calm default's arms may not come near the body at all)."""
    checkpoint = load_checkpoint(default_checkpoint_path(), robot=robot)
    assert checkpoint.model.config.body_band_m > 0
    off = replace(checkpoint, model=checkpoint.model.with_sampling(body_band_m=0.0))
    near = {"on": [], "off": []}
    for path in bundled_speech_paths()[:3]:
        audio = read_wav(path)[0]
        for name, model in (("on", checkpoint), ("off", off)):
            for angles in synthesize_samples(model, audio, range(8)):
                near[name].append(body.clearance(angles) < 0.02)
    share = {k: 100 * np.concatenate(v).mean() for k, v in near.items()}
    assert share["on"] < 1.0, share
    assert share["on"] <= share["off"], share


def _count_pairs(monkeypatch):
    """Record, per query of the capsule model, how many pairs it measured (either path)."""
    queries = []
    real = capsules._segment_gaps

    def counted(vectors):
        queries.append(vectors.shape[1] * vectors.shape[3])  # poses x pairs
        return real(vectors)

    monkeypatch.setattr(capsules, "_segment_gaps", counted)
    return queries


def test_when_an_arm_stays_far_from_the_body_expect_no_distance_query_yet_the_same_factors(
    robot, monkeypatch
):
    """A query costs more than the rest of a frame's body work: far from the body, a bound on
    the travel suffices."""
    noise = BodyNoise(robot, margin_m=0.02, band_m=0.03)
    track = _track(robot, 200, lambda x: x**3)  # slow, then fast
    clearance = noise.body.clearance(track)
    noise.factors(robot.normalize(track[0]))
    queries = _count_pairs(monkeypatch)
    got = [float(noise.factors(robot.normalize(p))[0]) for p in track[1:]]
    _assert_faded(got, clearance[1:], 0.02, 0.03)
    assert 0 < len(queries) < 0.8 * (len(track) - 1)  # queried only where the bound fell short
    assert min(got) == 0.0


def _every_pair(noise):
    """Make ``noise`` take one sequence's factors as N rows do: every pair of a stale pose."""
    noise.factor = lambda unit: float(noise._factors_of_rows(unit[None])[0])


def _wander(robot, n, seed):
    """n poses of both arms wandering about the body, slowly and by jumps, within the limits."""
    rng = np.random.default_rng(seed)
    steps = rng.normal(0.0, 0.01, (n, robot.n_joints)) * rng.choice([1, 10], (n, 1), p=[0.95, 0.05])
    start = pose_with(robot, **INSIDE, **RIGHT_AWAY)
    return np.clip(start + np.cumsum(steps, axis=0), robot.lower_rad, robot.upper_rad)


def test_when_poses_wander_about_the_body_expect_the_factors_of_measuring_every_pair(
    robot, monkeypatch
):
    """Each pair's own bound spares measuring most pairs, never changing a factor's last bit."""
    poses = [robot.normalize(p) for p in _wander(robot, 1500, 4)]
    queries = _count_pairs(monkeypatch)
    reference = BodyNoise(robot, 0.02, 0.03)
    _every_pair(reference)
    expected = [reference.factor(p) for p in poses]
    every = sum(queries)
    queries.clear()
    noise = BodyNoise(robot, 0.02, 0.03)
    got = [noise.factor(p) for p in poses[:700]]
    noise = pickle.loads(pickle.dumps(noise))  # a sampler sent to a worker mid-sequence
    got += [noise.factor(p) for p in poses[700:]]
    assert got == expected
    assert {0.0, 1.0} <= set(got)  # near and far
    assert sum(0.0 < f < 1.0 for f in got) > 100  # and in the band
    assert sum(queries) < every / 5, (sum(queries), every)
    noise.reset()
    assert [noise.factors(p[None])[0] for p in poses[:50]] == expected[:50]


@pytest.mark.parametrize("runtime", ["numpy", "torch"])
def test_when_the_packaged_model_streams_real_speech_expect_the_poses_of_measuring_every_pair(
    robot, monkeypatch, runtime
):
    """The streaming predictors (the node's numpy kernel, the model's own) on every bundled
    clip: the same poses to the last bit as measuring every pair of a stale pose, from about
    a tenth of the pairs (each pair's own bound; 221 pairs a frame when every pair of a stale
    pose is measured)."""
    from audio2pose_ros.checkpoints.numpy_runtime import load_streaming_model

    streaming = load_streaming_model(default_checkpoint_path(), robot=robot)
    raw = np.concatenate(
        [extract_features(read_wav(p)[0], streaming.features) for p in bundled_speech_paths()]
    )
    frames = np.clip(streaming.normalizer.apply(raw), -8.0, 8.0)
    assert len(frames) >= 2000

    def predictor():  # the model's own, without the node's warm start
        if runtime == "numpy":
            return streaming.predictor(seed=0).predictor
        return load_checkpoint(default_checkpoint_path(), robot=robot).model.streaming_predictor()

    queries = _count_pairs(monkeypatch)
    reference = predictor()
    _every_pair(reference._body_noise)
    expected = np.array([reference.step(f) for f in frames])
    every = sum(queries) / len(frames)
    queries.clear()
    new = predictor()
    got = np.array([new.step(f) for f in frames])
    assert np.array_equal(got, expected)
    assert sum(queries) / len(frames) < 50 < every, (sum(queries) / len(frames), every)


def test_when_a_streaming_predictor_is_made_expect_its_body_model_loaded_before_the_first_frame(
    robot,
):
    """The first frame of a node's first utterance must not wait for the URDF; the capsule
    model is plain numpy, so a pickled sampler takes it along."""
    from audio2pose_ros.checkpoints.numpy_runtime import load_streaming_model

    kernel = load_streaming_model(default_checkpoint_path(), robot=robot).predictor(seed=0)
    model = load_checkpoint(default_checkpoint_path(), robot=robot).model
    for predictor in (kernel, model.streaming_predictor(seed=0)):
        inner = getattr(predictor, "predictor", predictor)  # under its warm start, if any
        noise = inner._body_noise
        assert noise is not None
        assert isinstance(noise.body, CapsuleModel)
    near = robot.normalize(_track(robot, 10)[-3])
    original = BodyNoise(robot, margin_m=0.02, band_m=0.03)
    revived = pickle.loads(pickle.dumps(original))
    assert isinstance(revived.body, CapsuleModel)
    np.testing.assert_array_equal(revived.factors(near), original.factors(near))

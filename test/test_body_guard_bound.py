"""The guard's travel bound: a cheaper way to the same commands, never a looser check.

A command whose whole path the travel bound keeps at the floor passes without a clearance
query. These tests hold the guard with the bound to the guard that queries every check
(``travel_bound=False``): the same commands, bit for bit, over real speech; a bound that never
exceeds the exact clearance; and fewer queries where the arms are far from the body.
"""

from __future__ import annotations

import numpy as np
import pytest
from body_poses import AWAY, RIGHT_AWAY, pose_with

from audio2pose_ros.motion.body_guard import BodyGuard
from audio2pose_ros.motion.limits import JointLimiter, LimitSettings
from audio2pose_ros.robot.body import CULL_SLACK_M, BodyModel

RATE_HZ = 100.0


@pytest.fixture(scope="module")
def body():
    return BodyModel.load()


@pytest.fixture(scope="module")
def speech_poses(robot, speech):
    """The packaged model's raw poses over the bundled speech (unsmoothed, unguarded)."""
    from audio2pose_ros.checkpoints.torch_io import load_checkpoint
    from audio2pose_ros.offline.synthesis import synthesize
    from audio2pose_ros.resources import default_checkpoint_path

    checkpoint = load_checkpoint(default_checkpoint_path(), robot=robot)
    return synthesize(checkpoint, speech[: 16000 * 6], smooth=False, body_margin_m=None)[1]


def run(guard, poses, margins, settings=None):
    """Commands and statuses of ``guard`` over ``poses`` behind the joint limits, as the filter
    runs them, with ``margins[i]`` the margin at frame i (set live)."""
    limiter = JointLimiter(guard.body.robot, settings)
    dt_s = 1.0 / RATE_HZ
    guard.reset()
    previous = limiter.clamp_position(poses[0])
    velocity = np.zeros(poses.shape[1])
    commands, statuses = [], []
    for pose, margin in zip(poses, margins, strict=True):
        guard.margin_m = margin
        want, want_velocity = limiter.enforce(pose, previous, velocity, dt_s)
        previous, velocity = guard.enforce(want, want_velocity, previous, velocity, dt_s, limiter)
        commands.append(np.concatenate([previous, velocity]))
        s = guard.status
        statuses.append((s.interventions, s.lead_out_steps, s.holds, s.detour_steps, s.floor_m))
    return np.array(commands), statuses


def count_measurements(body, monkeypatch):
    """A list that counts the pairs the body model measures with coal from now on."""
    measured = []
    original = body._measure

    def counted(pose, pairs):
        measured.append(len(pairs))
        return original(pose, pairs)

    monkeypatch.setattr(body, "_measure", counted)
    return measured


def fresh_searches(body, monkeypatch):
    """Start each of coal's distance searches from its first guess, not the pair's last answer.

    coal's answers depend, within its 1e-6 m tolerance, on the queries before (the body model
    starts each search from the pair's previous answer). A guard that queries less has another
    history, and near the body some of its decisions compare two such answers (a resting arm
    inside the margin: the command's clearance against the previous one's) or differentiate
    them (a detour's gradient): they follow coal's rounding, with or without the bound. With
    each search from its first guess, an answer depends on its pose alone.
    """
    group = body._pairs
    group.reset_guesses()
    first = [
        (r.cached_gjk_guess.copy(), r.cached_support_func_guess.copy()) for r in group.requests
    ]
    original = body._measure

    def measure(pose, pairs):
        for k in pairs.tolist():
            group.requests[k].cached_gjk_guess = first[k][0]
            group.requests[k].cached_support_func_guess = first[k][1]
        return original(pose, pairs)

    monkeypatch.setattr(body, "_measure", measure)


def guarded_both_ways(body, poses, margins):
    """(commands, statuses, guard) of the guard without and with the bound over ``poses``."""
    exact, exact_status = run(BodyGuard(body, 0.02, travel_bound=False), poses, margins)
    guard = BodyGuard(body, 0.02)
    bounded, bounded_status = run(guard, poses, margins)
    return (exact, exact_status), (bounded, bounded_status), guard


def test_when_real_speech_guarded_with_and_without_the_travel_bound_expect_the_same_commands(
    body, speech_poses
):
    """At the default margin, as the filter runs (coal's searches from their last answers):
    bit-equal commands, velocities and counters, the bound answering nearly every check."""
    n = len(speech_poses)
    (exact, exact_status), (bounded, bounded_status), guard = guarded_both_ways(
        body, speech_poses, np.full(n, 0.02)
    )
    assert n >= 500
    np.testing.assert_array_equal(bounded, exact)
    assert bounded_status == exact_status
    assert guard.status.bound_checks > 0.9 * n


@pytest.mark.parametrize(
    "margins",
    [
        "wide",  # 4.8 cm: on real speech the guard brakes, slides and goes round
        "raised live",  # 2 cm, raised to 5 cm (arms inside it: led out), lowered to 1 cm
    ],
)
def test_when_real_speech_guarded_near_the_body_expect_the_same_decisions_with_the_bound(
    body, speech_poses, margins, monkeypatch
):
    """Near the body, with coal's answers depending on their poses alone (:func:`fresh_searches`):
    bit-equal commands, velocities and counters; the bound answers some checks, not all."""
    fresh_searches(body, monkeypatch)
    n = len(speech_poses)
    third = np.arange(n) * 3 // n
    margin = {"wide": np.full(n, 0.048), "raised live": np.array([0.02, 0.05, 0.01])[third]}
    (exact, exact_status), (bounded, bounded_status), guard = guarded_both_ways(
        body, speech_poses, margin[margins]
    )
    np.testing.assert_array_equal(bounded, exact)
    assert bounded_status == exact_status
    assert exact_status[-1][0] > 100  # near the body: the guard changed many commands ...
    assert 0 < guard.status.bound_checks < n  # ... and checked them with queries


def test_when_commands_pass_the_bound_expect_reported_clearance_a_lower_bound(body, speech_poses):
    """The status says when its clearance is a bound, and the bound is never above the truth."""
    limiter = JointLimiter(body.robot)
    guard = BodyGuard(body, 0.02)
    guard.reset()
    previous = limiter.clamp_position(speech_poses[0])
    velocity = np.zeros(speech_poses.shape[1])
    kinds = set()
    for pose in speech_poses[:300]:
        want, want_velocity = limiter.enforce(pose, previous, velocity, 1.0 / RATE_HZ)
        previous, velocity = guard.enforce(
            want, want_velocity, previous, velocity, 1.0 / RATE_HZ, limiter
        )
        status = guard.status
        exact = body.pair_distances(previous)
        kinds.add(status.clearance_exact)
        if status.clearance_exact:
            assert status.clearance_m == pytest.approx(exact.min(), abs=CULL_SLACK_M)  # coal
        else:
            assert status.clearance_m <= exact.min()
            assert status.clearance_m >= guard.margin_m  # the bound cleared it
        assert status.links in body.link_pairs
    assert kinds == {True, False}


def test_when_random_poses_and_paths_expect_the_bounds_never_above_the_exact_clearance(body):
    """Property: from any measurements, each pair's bound at a pose less its levers times the
    travel to a nearby pose never exceeds that pair's exact distance there, and the guard's
    bound of a whole path (step and braking path) never exceeds the clearance of any of the
    points it checks."""
    rng = np.random.default_rng(7)
    robot = body.robot
    lower, upper = robot.lower_rad, robot.upper_rad
    limiter = JointLimiter(robot)
    guard = BodyGuard(body, 0.0)
    for _ in range(60):
        body.reset()
        measured_at = rng.uniform(lower, upper)
        body.query(measured_at)  # the first query measures every pair: there it is tight
        tight = body.pair_bounds(measured_at)
        exact = body.pair_distances(measured_at)  # coal: within 1e-6 m of the first answers
        assert np.all((tight <= exact) & (tight >= exact - 2.0 * CULL_SLACK_M))
        for _ in range(rng.integers(0, 4)):  # later ones some pairs only, elsewhere
            body.query(np.clip(measured_at + rng.normal(0.0, 0.2, robot.n_joints), lower, upper))
        previous = np.clip(measured_at + rng.normal(0.0, 0.1, robot.n_joints), lower, upper)
        bounds = body.pair_bounds(previous)
        exact = body.pair_distances(previous)
        assert np.all(bounds <= exact)
        step = rng.normal(0.0, 0.02, robot.n_joints)
        pose = np.clip(previous + step, lower, upper)
        velocity = rng.normal(0.0, 1.0, robot.n_joints) * robot.max_velocity_rad_s / 3.0
        accel = limiter.max_acceleration_rad_s2
        # the guard's state in a step from ``previous``, as enforce sets it
        guard._previous = previous
        guard._bounds = limiter.allowed_range(previous)
        guard._pair_bounds_m = body.pair_bounds(previous)
        path_bound = guard._path_bound(pose, velocity, accel)
        points, counts = guard._path(pose, velocity, accel)
        samples = [points[0]]
        for start, end, count in zip(points[:-1], points[1:], counts, strict=True):
            samples.extend(start + (end - start) * np.arange(1, count + 1)[:, None] / count)
        clearance = np.array([body.pair_distances(q).min() for q in samples[::7]])
        assert path_bound <= clearance.min()
        assert path_bound <= float(body.clearance(pose))


def test_when_arms_far_from_the_body_expect_far_fewer_clearance_queries(body, monkeypatch):
    """Counts, not time: arms swinging well clear of the body need no query after the first
    steps with the bound, and a query every step without it."""
    robot = body.robot
    away = pose_with(robot, **AWAY, **RIGHT_AWAY)
    swing = np.zeros(robot.n_joints)
    swing[[robot.names.index("LElbowYaw"), robot.names.index("RElbowYaw")]] = 0.15
    poses = away + np.sin(np.arange(400) / 15.0)[:, None] * swing
    assert float(body.clearance(poses).min()) > 0.05
    margins = np.full(len(poses), 0.02)
    settings = LimitSettings(position_margin_rad=0.0)
    measured = count_measurements(body, monkeypatch)
    exact, _ = run(BodyGuard(body, 0.02, travel_bound=False), poses, margins, settings)
    exact_calls = len(measured)
    measured.clear()
    guard = BodyGuard(body, 0.02)
    bounded, _ = run(guard, poses, margins, settings)
    np.testing.assert_array_equal(bounded, exact)
    assert exact_calls >= len(poses)  # without the bound: every step measures
    assert len(measured) <= 5  # with it: the first steps only
    assert guard.status.bound_checks >= len(poses) - 5
    assert not guard.status.clearance_exact


def test_when_margin_raised_above_the_bound_expect_the_guard_queries_again(body, monkeypatch):
    """A margin raised live beyond what the bound can show makes every check exact again."""
    robot = body.robot
    away = pose_with(robot, **AWAY, **RIGHT_AWAY)
    poses = np.repeat(away[None, :], 60, axis=0)
    raised = float(body.clearance(away)) + 0.01
    measured = count_measurements(body, monkeypatch)
    steady = BodyGuard(body, 0.02)
    run(steady, poses, np.full(60, 0.02))
    steady_calls = len(measured)
    measured.clear()
    guard = BodyGuard(body, 0.02)
    run(guard, poses, np.where(np.arange(60) < 30, 0.02, raised))
    assert steady.status.bound_checks >= 55
    assert steady_calls <= 5
    assert 25 <= guard.status.bound_checks <= 30  # up to the raise
    assert guard.status.lead_out_steps > 0  # then led out, with queries
    assert guard.status.clearance_exact
    assert len(measured) >= steady_calls + 30

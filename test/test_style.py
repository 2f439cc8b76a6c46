"""The style transform: identity when neutral, causal, bounded, no jump, hostile values refused."""

import math

import numpy as np
import pytest

from audio2pose_ros.errors import ConfigurationError, InputError
from audio2pose_ros.motion.style import STYLE_BLEND_S, StyleSettings, StyleTransform
from audio2pose_ros.robot.description import load_robot

RATE = 100.0


@pytest.fixture(scope="module")
def robot():
    return load_robot()


def wander(robot, n=600, seed=0):
    """Smooth random motion inside the joint ranges."""
    rng = np.random.default_rng(seed)
    steps = rng.normal(0.0, 0.02, (n, robot.n_joints)).cumsum(axis=0)
    kernel = np.ones(15) / 15
    smooth = np.array(
        [np.convolve(steps[:, j], kernel, mode="same") for j in range(steps.shape[1])]
    ).T
    return np.clip(robot.neutral_rad + smooth, robot.lower_rad + 0.1, robot.upper_rad - 0.1)


def test_when_style_is_neutral_expect_identity(robot):
    motion = wander(robot)
    np.testing.assert_array_equal(StyleTransform(robot).run(motion), motion)
    stepped = StyleTransform(robot)
    np.testing.assert_allclose([stepped.step(p) for p in motion], motion, atol=1e-12)


@pytest.mark.parametrize(
    "settings",
    [
        StyleSettings(arms_tempo=0.3, head_tempo=0.5),
        StyleSettings(arms_tempo=2.0, hip_tempo=1.7, head_gain=2.0),
        StyleSettings(arms_rest_pitch_rad=0.3, arms_rest_bend_rad=-0.2, arms_raise_limit_rad=0.8),
    ],
)
def test_when_future_frames_change_expect_past_output_unchanged(robot, settings):
    motion = wander(robot)
    changed = motion.copy()
    changed[300:] += 0.5
    a = StyleTransform(robot, settings, RATE).run(motion)
    b = StyleTransform(robot, settings, RATE).run(changed)
    np.testing.assert_array_equal(a[:300], b[:300])
    assert not np.allclose(a[300:], b[300:])


def test_when_tempo_below_one_expect_slower_and_inside_the_input_range(robot):
    motion = wander(robot)
    out = StyleTransform(robot, StyleSettings(arms_tempo=0.4), RATE).run(motion)
    arms = robot.group_mask("arms")
    speed_in = np.abs(np.diff(motion[:, arms], axis=0)).mean()
    speed_out = np.abs(np.diff(out[:, arms], axis=0)).mean()
    assert speed_out < 0.8 * speed_in
    assert np.all(out[:, arms] <= motion[:, arms].max(axis=0) + 1e-12)
    assert np.all(out[:, arms] >= motion[:, arms].min(axis=0) - 1e-12)
    np.testing.assert_allclose(out[:, ~arms], motion[:, ~arms], atol=1e-12)  # others untouched


def test_when_gain_set_expect_scaled_about_neutral(robot):
    motion = wander(robot)
    out = StyleTransform(robot, StyleSettings(head_gain=0.5), RATE).run(motion)
    head = robot.group_mask("head")
    expected = robot.neutral_rad[head] + 0.5 * (motion[:, head] - robot.neutral_rad[head])
    np.testing.assert_allclose(out[:, head], expected)


def test_when_raise_limit_set_expect_shoulder_pitch_softly_above_it_and_monotonic(robot):
    pitch = robot.names.index("LShoulderPitch")
    pose = np.tile(robot.neutral_rad, (200, 1))
    pose[:, pitch] = np.linspace(-1.5, 1.5, 200)
    out = StyleTransform(robot, StyleSettings(arms_raise_limit_rad=0.5), RATE).run(pose)
    assert np.all(out[:, pitch] > 0.5)
    assert np.all(np.diff(out[:, pitch]) > 0)
    assert abs(out[-1, pitch] - 1.5) < 1e-4


def test_when_style_changes_live_expect_no_jump_and_new_style_after_the_blend(robot):
    motion = np.tile(robot.neutral_rad, (400, 1))
    arms = robot.group_mask("arms")
    motion[:, arms] += 0.4  # held away from neutral: a gain step would jump by 0.4 * 1.5 rad
    transform = StyleTransform(robot, StyleSettings(arms_tempo=0.3), RATE)
    out = [transform.step(p) for p in motion[:100]]
    transform.update(StyleSettings(arms_gain=2.0, arms_rest_pitch_rad=0.3, arms_tempo=2.0))
    out += [transform.step(p) for p in motion[100:]]
    steps = np.abs(np.diff(np.array(out), axis=0))
    assert steps.max() < 0.02  # at most 2 rad/s from the blend; a jump would be 0.6 rad
    blended = int(STYLE_BLEND_S * RATE) + 101
    expected = StyleTransform(
        robot, StyleSettings(arms_gain=2.0, arms_rest_pitch_rad=0.3, arms_tempo=2.0), RATE
    ).static(motion[0])
    np.testing.assert_allclose(out[blended], expected, atol=1e-9)


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("arms_gain", math.nan),
        ("head_gain", math.inf),
        ("hip_gain", -0.1),
        ("arms_gain", 1e9),
        ("head_tempo", 0.0),
        ("arms_tempo", 50.0),
        ("arms_rest_pitch_rad", 3.0),
        ("arms_raise_limit_rad", -math.inf),
        ("arms_gain", "1.0"),
    ],
)
def test_when_style_value_hostile_expect_clear_refusal(name, value):
    with pytest.raises(ConfigurationError, match=f"parameter {name}: value .* allowed"):
        StyleSettings(**{name: value})


def test_when_pose_bad_expect_input_error(robot):
    transform = StyleTransform(robot, StyleSettings(arms_gain=0.5))
    with pytest.raises(InputError, match="angles"):
        transform.step(np.zeros(3))
    bad = wander(robot, 10)
    bad[4, 2] = math.nan
    with pytest.raises(InputError, match="non-finite"):
        transform.run(bad)


def test_when_extreme_style_expect_finite_output(robot):
    motion = wander(robot)
    motion[::7] = robot.upper_rad
    motion[3::7] = robot.lower_rad
    extreme = StyleSettings(
        head_gain=2.0, arms_gain=2.0, hip_gain=0.0, arms_tempo=2.0, head_tempo=0.2,
        arms_rest_pitch_rad=-0.6, arms_raise_limit_rad=1.5708,
    )  # fmt: skip
    out = StyleTransform(robot, extreme, RATE).run(motion)
    assert np.isfinite(out).all()


def test_when_deprecated_filter_gain_given_expect_warning_and_the_style_size_set(robot):
    from audio2pose_ros.motion.filter import MotionFilter
    from audio2pose_ros.motion.filter_settings import MotionFilterSettings

    with pytest.warns(DeprecationWarning, match="use StyleSettings"):
        settings = MotionFilterSettings(arms_gain=0.0)
    assert MotionFilter(robot, settings).style.settings.arms_gain == 0.0
    with (
        pytest.raises(ConfigurationError, match="arms_gain"),
        pytest.warns(DeprecationWarning, match="deprecated"),
    ):
        MotionFilterSettings(arms_gain=math.nan)


def test_when_a_style_is_set_on_the_identity_mid_stream_expect_no_jump(robot):
    motion = wander(robot, 400)
    transform = StyleTransform(robot, rate_hz=RATE)
    out = [transform.step(p) for p in motion[:200]]
    style = StyleSettings(arms_tempo=0.3, arms_gain=2.0, head_tempo=2.0)
    transform.update(style)
    out += [transform.step(p) for p in motion[200:]]
    steps = np.abs(np.diff(np.array(out), axis=0)).max(axis=1)
    styled = StyleTransform(robot, style, RATE).run(motion)
    assert steps[199] < 1.01 * steps[:199].max()  # the change itself adds no step
    # during and after the blend no faster than the style applied from the start
    assert steps[200:].max() <= 1.2 * np.abs(np.diff(styled, axis=0)).max()


@pytest.mark.parametrize(
    ("before", "after"),
    [
        (StyleSettings(), StyleSettings(arms_raise_limit_rad=0.5)),  # switched on
        (StyleSettings(arms_raise_limit_rad=0.5), StyleSettings()),  # switched off
        (StyleSettings(arms_gain=1.5), StyleSettings(arms_gain=0.5)),  # off on both sides
    ],
    ids=["on", "off", "neither"],
)
def test_when_the_raise_limit_switches_live_expect_it_faded_finite_and_without_a_jump(
    robot, before, after
):
    """A height limit switched on or off blends like any other style value: no NaN, no snap."""
    pitch = robot.names.index("LShoulderPitch")
    motion = np.tile(robot.neutral_rad, (300, 1))
    motion[:, pitch] = -0.5  # the arm raised, above the limit: the limit moves it by ~1 rad
    transform = StyleTransform(robot, before, RATE)
    out = [transform.step(p) for p in motion[:50]]
    transform.update(after)
    with np.errstate(invalid="raise"):  # a NaN made inside the blend is an error here
        out += [transform.step(p) for p in motion[50:]]
    out_arr = np.array(out)
    assert np.isfinite(out_arr).all()
    steps = np.abs(np.diff(out_arr[:, pitch]))
    assert steps.max() < 0.05  # faded over the blend; a snap at its end would be ~1 rad
    expected = StyleTransform(robot, after, RATE).static(motion[0])
    np.testing.assert_allclose(out_arr[-1], expected, atol=1e-9)

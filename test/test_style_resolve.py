"""Resolving a person's figures into style settings against a model's motion (small data)."""

import dataclasses

import numpy as np
import pytest

from audio2pose_ros.motion.style import MAX_GAIN, style_trajectory
from audio2pose_ros.style.figures import measure_part, resolve

RATE = 100.0


def arm_motion(robot, bend_rad, n=800, seed=0):
    """Smooth random motion about a pose with the elbows bent ``bend_rad``, every frame known."""
    rng = np.random.default_rng(seed)
    base = robot.neutral_rad.copy()
    for j, name in enumerate(robot.names):
        if name.endswith("ElbowRoll"):
            base[j] = -bend_rad if name.startswith("L") else bend_rad
    steps = rng.normal(0.0, 0.01, (n, robot.n_joints)).cumsum(axis=0)
    kernel = np.ones(25) / 25
    smooth = np.array([np.convolve(s, kernel, mode="same") for s in steps.T]).T
    angles = np.clip(base + smooth - smooth.mean(axis=0), robot.lower_rad, robot.upper_rad)
    return [(angles, np.ones(angles.shape, dtype=bool))]


def scaled(figures, size, speed, **changes):
    """The figures of motion ``size`` times as large and ``speed`` times as fast, and changes."""
    return dataclasses.replace(
        figures,
        std_rad=figures.std_rad * size,
        speed_deciles_rad_s=tuple(v * speed for v in figures.speed_deciles_rad_s),
        accel_deciles_rad_s2=tuple(v * speed for v in figures.accel_deciles_rad_s2),
        **changes,
    )


def test_when_a_person_is_still_between_gestures_expect_the_style_fitted_to_their_gestures(
    robot,
):
    # Two people larger than the largest size can make the model, alike in their faster half
    # of motion; one rests about half of the time (deciles p10 to p50 five times lower). A
    # causal linear style cannot make motion intermittent: fitted to the low deciles too, it
    # slowed the whole motion down towards the stillness (tempo 0.7 here, 0.5 on the lecture).
    model = arm_motion(robot, bend_rad=0.8)
    mover = scaled(measure_part(model, robot, "arms", RATE), size=4.0, speed=2.0)

    def resting(deciles):
        return tuple(v / 5 for v in deciles[:5]) + deciles[5:]

    rester = dataclasses.replace(
        mover,
        speed_deciles_rad_s=resting(mover.speed_deciles_rad_s),
        accel_deciles_rad_s2=resting(mover.accel_deciles_rad_s2),
    )
    as_mover = resolve({"arms": mover}, model, robot, RATE)
    assert (as_mover.arms_tempo, as_mover.arms_gain) == (1.0, MAX_GAIN)
    assert resolve({"arms": rester}, model, robot, RATE) == as_mover


def test_when_the_size_bends_the_elbows_past_the_figure_bound_expect_them_at_the_person_rest(
    robot,
):
    # The model's elbows rest bent 1.2 rad (0.68 from neutral); at the largest size they would
    # rest at 1.88 rad, past the 1.6 rad bound of a measured rest figure. The rest offset must
    # bring them back to the person's 1.3 rad, not to 1.3 + (1.88 - 1.6).
    model = arm_motion(robot, bend_rad=1.2)
    figures = measure_part(model, robot, "arms", RATE)
    person = scaled(figures, size=3.0, speed=3.0, rest_bend_rad=1.3)
    settings = resolve({"arms": person}, model, robot, RATE)
    assert settings.arms_gain == MAX_GAIN  # the size the test is about
    styled = style_trajectory(robot, settings, model[0][0], RATE)
    bends = [
        (-1.0 if name.startswith("L") else 1.0) * styled[:, j]
        for j, name in enumerate(robot.names)
        if name.endswith("ElbowRoll")
    ]
    assert float(np.median(np.concatenate(bends))) == pytest.approx(1.3, abs=0.02)


def test_when_a_still_person_moves_at_the_models_speed_expect_a_tempo_past_two_that_keeps_it(
    robot,
):
    # GRID speaker s1: 0.4 of the model's head size at the model's speed. Size alone slows the
    # motion with it; with the tempo capped at 2 his enrolled head moved at 0.6 to 0.8 of his
    # speed (5 of 12 percentiles within 25 %), with up to 3 at 10 of 12.
    model = arm_motion(robot, bend_rad=0.8)
    person = scaled(measure_part(model, robot, "arms", RATE), size=0.4, speed=1.0)
    settings = resolve({"arms": person}, model, robot, RATE)
    assert settings.arms_tempo > 2.0

    def speed_ratio(style) -> float:
        styled = style_trajectory(robot, style, model[0][0], RATE)
        figures = measure_part([(styled, model[0][1])], robot, "arms", RATE)
        return float(
            np.median(np.divide(figures.speed_deciles_rad_s[4:], person.speed_deciles_rad_s[4:]))
        )

    capped = dataclasses.replace(settings, arms_tempo=2.0)
    assert speed_ratio(capped) < speed_ratio(settings) < 1.25

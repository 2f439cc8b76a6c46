"""Joint limits applied last: position, velocity, acceleration (ros2_control's order)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.motion.limits import MIN_DT_S, JointLimiter, LimitSettings

DT = 0.01


@pytest.fixture
def limiter(robot):
    return JointLimiter(robot, LimitSettings(position_margin_rad=0.01, velocity_fraction=0.5))


def test_when_target_beyond_range_expect_clamp_inside_margin(limiter, robot):
    pos, vel = robot.neutral_rad.copy(), np.zeros(11)
    for _ in range(2000):  # long enough to reach any target
        pos, vel = limiter.enforce(robot.upper_rad + 5.0, pos, vel, DT)
    np.testing.assert_allclose(pos, robot.upper_rad - 0.01, atol=1e-9)
    assert limiter.counts.position > 0


def test_when_jump_requested_expect_velocity_capped(limiter, robot):
    pos, vel = robot.neutral_rad.copy(), np.zeros(11)
    target = robot.neutral_rad + 0.5
    for _ in range(50):
        new_pos, vel = limiter.enforce(target, pos, vel, DT)
        assert np.all(np.abs(new_pos - pos) / DT <= limiter.max_velocity_rad_s + 1e-9)
        pos = new_pos
    assert limiter.counts.velocity > 0


def test_when_nan_or_inf_desired_expect_previous_position_held(limiter, robot):
    pos = robot.neutral_rad.copy()
    desired = pos.copy()
    desired[0], desired[3] = np.nan, np.inf
    out, vel = limiter.enforce(desired, pos, np.zeros(11), DT)
    np.testing.assert_allclose(out, pos)
    np.testing.assert_allclose(vel, 0.0)
    assert limiter.counts.non_finite == 2


def test_when_dt_not_positive_expect_previous_command_unchanged(limiter, robot):
    pos, vel = robot.neutral_rad.copy(), np.full(11, 0.1)
    for dt in (0.0, -0.01, float("nan"), 1e-9):
        out, out_vel = limiter.enforce(robot.upper_rad, pos, vel, dt)
        np.testing.assert_array_equal(out, pos)
        np.testing.assert_array_equal(out_vel, vel)


def test_when_settings_out_of_range_expect_configuration_error_naming_parameter():
    with pytest.raises(ConfigurationError, match=r"velocity_fraction: value 1.5 is out of range"):
        LimitSettings(velocity_fraction=1.5)
    with pytest.raises(ConfigurationError, match=r"position_margin_rad: value -0.1 is out of"):
        LimitSettings(position_margin_rad=-0.1)
    with pytest.raises(ConfigurationError, match="position_margin_rad: value nan is not finite"):
        LimitSettings(position_margin_rad=float("nan"))


finite_or_not = st.one_of(
    st.floats(min_value=-1e6, max_value=1e6),
    st.sampled_from([np.nan, np.inf, -np.inf, 1e300, -1e300]),
)


SEQUENCES = (
    st.lists(st.lists(finite_or_not, min_size=11, max_size=11), min_size=1, max_size=60),
    st.lists(st.floats(min_value=-0.02, max_value=0.05), min_size=60, max_size=60),
)


def limits_hold(robot, sequence, dts) -> None:
    """Every command of ``sequence`` (steps of ``dts``) is finite and within all limits."""
    limiter = JointLimiter(robot)
    pos, vel = robot.neutral_rad.copy(), np.zeros(11)
    for desired, dt in zip(sequence, dts, strict=False):
        new_pos, new_vel = limiter.enforce(np.array(desired), pos, vel, dt)
        assert np.all(np.isfinite(new_pos))
        assert np.all(new_pos >= limiter.lower_rad - 1e-12)
        assert np.all(new_pos <= limiter.upper_rad + 1e-12)
        if dt >= MIN_DT_S:
            assert np.all(np.abs(new_vel) <= limiter.max_velocity_rad_s + 1e-9)
            assert np.all(np.abs(new_vel - vel) / dt <= limiter.max_acceleration_rad_s2 + 1e-6)
        pos, vel = new_pos, new_vel


@settings(max_examples=300, deadline=None, derandomize=True)  # reproducible in CI
@given(*SEQUENCES)
def test_when_any_input_sequence_expect_all_limits_hold(robot, sequence, dts):
    limits_hold(robot, sequence, dts)


@pytest.mark.long  # the same property over 2,000 sequences: make test-long
@settings(max_examples=2000, deadline=None, derandomize=True)
@given(*SEQUENCES)
def test_when_any_of_2000_input_sequences_expect_all_limits_hold(robot, sequence, dts):
    limits_hold(robot, sequence, dts)


@pytest.mark.parametrize("fraction", [0.5, 0.1, 0.02])
def test_when_acceleration_is_lowered_while_a_joint_races_to_its_limit_expect_no_dead_stop(
    robot, fraction
):
    """A live-lowered acceleration_fraction (MotionFilter.update_settings): a joint moving at
    full speed towards its position limit could not stop at the new, lower deceleration. It
    must brake as the previous limit allowed, never harder, until it can stop at the new one;
    before, the limiter stopped it at its position limit in one command (3.31 rad/s to 0 in
    10 ms)."""
    from audio2pose_ros.motion.filter import MotionFilter, MotionFilterSettings

    fast = LimitSettings(velocity_fraction=1.0, acceleration_fraction=1.0)
    start = robot.neutral_rad.copy()
    filt = MotionFilter(robot, MotionFilterSettings(smoothing="none"), fast, start_pose_rad=start)
    old_accel = filt.limiter.max_acceleration_rad_s2.copy()
    pos, vel = start.copy(), np.zeros(robot.n_joints)
    goal = robot.upper_rad + 1.0  # beyond every limit: each joint races to its upper limit
    lowered = False
    for step in range(600):
        if not lowered and (np.abs(vel) >= 0.9 * filt.limiter.max_velocity_rad_s).any():
            filt.update_settings(
                filt.settings, LimitSettings(velocity_fraction=1.0, acceleration_fraction=fraction)
            )
            lowered = True
        new_pos, new_vel = filt.limiter.enforce(goal, pos, vel, DT)
        assert np.all(np.abs(new_vel - vel) <= old_accel * DT + 1e-9), step
        assert np.all(new_pos <= robot.upper_rad + 1e-12)
        pos, vel = new_pos, new_vel
    assert lowered
    np.testing.assert_allclose(vel, 0.0, atol=1e-9)  # at rest at the limits
    np.testing.assert_allclose(filt.limiter.braking_rad_s2, filt.limiter.max_acceleration_rad_s2)


def test_when_a_racing_joint_is_sent_back_after_a_lowered_acceleration_expect_it_braked_in_time(
    robot,
):
    """The same, with the target behind the joint (it has to reverse): it first has to stop,
    and stopping is braking, at the previous limit while it needs it; before, a reversal was
    slowed at the new, lower limit only and the joint was stopped at its position limit."""
    from audio2pose_ros.motion.filter import MotionFilter, MotionFilterSettings

    fast = LimitSettings(velocity_fraction=1.0, acceleration_fraction=1.0)
    start = robot.neutral_rad.copy()
    filt = MotionFilter(robot, MotionFilterSettings(smoothing="none"), fast, start_pose_rad=start)
    old_accel = filt.limiter.max_acceleration_rad_s2.copy()
    pos, vel = start.copy(), np.zeros(robot.n_joints)
    goal = robot.upper_rad + 1.0
    for _ in range(400):
        if (np.abs(vel) >= 0.9 * filt.limiter.max_velocity_rad_s).any():
            break
        pos, vel = filt.limiter.enforce(goal, pos, vel, DT)
    filt.update_settings(
        filt.settings, LimitSettings(velocity_fraction=1.0, acceleration_fraction=0.05)
    )
    back = start.copy()  # where the joints came from: behind them
    for step in range(3000):
        new_pos, new_vel = filt.limiter.enforce(back, pos, vel, DT)
        assert np.all(np.abs(new_vel - vel) <= old_accel * DT + 1e-9), step
        assert np.all(new_pos <= robot.upper_rad + 1e-12)
        pos, vel = new_pos, new_vel
    np.testing.assert_allclose(pos, back, atol=1e-3)  # and it got back


def test_when_the_range_is_asked_again_expect_the_kept_answer_only_for_the_same_pose(
    limiter, robot
):
    """allowed_range keeps its last answer: right for a changed pose, never writable."""
    outside = robot.upper_rad.copy()  # at the robot's limit, between it and the margin
    upper = limiter.allowed_range(outside)[1]
    assert np.array_equal(upper, robot.upper_rad)
    with pytest.raises(ValueError, match="read-only"):
        upper[0] = 0.0
    inside = robot.neutral_rad.copy()
    upper = limiter.allowed_range(inside)[1]
    assert np.array_equal(upper, limiter.upper_rad)
    inside[0] = robot.upper_rad[0]  # the same array changed in place: a new answer
    assert limiter.allowed_range(inside)[1][0] == robot.upper_rad[0]

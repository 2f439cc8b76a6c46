"""Property suite of the motion filter core: whatever arrives, every command is safe.

Hypothesis feeds arbitrary event sequences into MotionFilter: finite values of any size
(in-range, 90 rad, 1e50, 1e308) and non-finite ones, poses one at a time or in messages of any
size, time that jumps forwards (gaps up to seconds) and backwards, restarts from any pose, stops,
head targets and offsets. After every tick the command must be finite, inside the position
limits, inside the velocity limits, and must not change position or velocity faster than the
limits allow for the time step (the very first step included). Derandomized: CI runs the same
examples every time.
"""

import contextlib
import dataclasses

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from audio2pose_ros.errors import InputError
from audio2pose_ros.motion.filter import GAP_PERIODS, MotionFilter
from audio2pose_ros.motion.filter_settings import MotionFilterSettings
from audio2pose_ros.motion.style import MAX_TEMPO, MIN_TEMPO, STYLE_FIELDS
from audio2pose_ros.motion.timing import StampCheck

PERIOD = 0.01
N_JOINTS = 11

values = st.one_of(
    st.floats(min_value=-3.0, max_value=3.0),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([90.0, -90.0, 1e6, 1e50, 1e308, -1e308, np.nan, np.inf, -np.inf]),
)
poses = st.lists(values, min_size=N_JOINTS, max_size=N_JOINTS)


@st.composite
def event_sequences(draw):
    kinds = st.sampled_from(
        [
            "pose",
            "pose",
            "pose",
            "message",
            "tick",
            "tick",
            "tick",
            "voice",
            "enable",
            "stop",
            "head",
            "offset",
            "time",
            "restart",
            "settings",
        ]
    )
    events = []
    for _ in range(draw(st.integers(min_value=1, max_value=80))):
        kind = draw(kinds)
        if kind == "pose":
            events.append((kind, [draw(poses)]))
        elif kind == "message":
            size = draw(st.sampled_from([0, 2, 7, 30, 250]))
            base = np.array(draw(poses))
            events.append((kind, np.tile(base, (size, 1)).tolist()))
        elif kind in ("voice", "enable", "stop"):
            events.append((kind, draw(st.booleans())))
        elif kind in ("head", "offset"):
            events.append((kind, (draw(values), draw(values))))
        elif kind == "time":
            events.append((kind, draw(st.sampled_from([-0.5, -0.001, 0.0005, 0.03, 0.2, 2.0]))))
        elif kind == "restart":
            events.append((kind, draw(poses)))
        elif kind == "settings":  # a live `ros2 param set` of what may change while running
            unit = st.floats(min_value=0.0, max_value=1.0)
            events.append(
                (
                    kind,
                    {
                        "arms_gain": draw(st.floats(min_value=0.0, max_value=2.0)),
                        "head_gain": draw(st.floats(min_value=0.0, max_value=2.0)),
                        "arms_tempo": draw(st.floats(min_value=MIN_TEMPO, max_value=MAX_TEMPO)),
                        "arms_rest_pitch_rad": draw(st.floats(min_value=-0.6, max_value=0.6)),
                        "arms_raise_limit_rad": draw(st.floats(min_value=-2.0857, max_value=1.5)),
                        "head_target_weight": draw(unit),
                        "outlier_tolerance_rad": draw(unit),
                        "max_head_offset_rad": draw(unit),
                        "stop_behaviour": draw(st.sampled_from(["hold", "neutral"])),
                        "neutral_glide_s": draw(st.sampled_from([0.05, 0.5, 3.0])),
                        "watchdog_timeout_s": draw(st.sampled_from([0.01, 0.5, 5.0])),
                        "max_points_per_message": draw(st.sampled_from([1, 5, 200])),
                    },
                )
            )
        else:
            events.append((kind, None))
    return events


def check_command(filt, pos, vel, prev_pos, prev_vel, elapsed):
    """Every limit holds for this command against the previous one."""
    limiter = filt.limiter
    assert np.all(np.isfinite(pos))
    assert np.all(np.isfinite(vel))
    # inside the margin-shrunk range, or (a start between a limit and the margin) moving inward
    lower, upper = limiter.allowed_range(prev_pos)
    assert np.all(pos >= lower - 1e-12)
    assert np.all(pos <= upper + 1e-12)
    assert np.all(pos >= limiter.robot_lower_rad)
    assert np.all(pos <= limiter.robot_upper_rad)
    assert np.all(np.abs(vel) <= limiter.max_velocity_rad_s + 1e-9)
    dt = min(elapsed, 2 * PERIOD)
    if dt >= 1e-6:
        assert np.all(np.abs(pos - prev_pos) <= limiter.max_velocity_rad_s * dt + 1e-9)
        # After a gap the velocity was braked over the whole gap, then limited over dt.
        allowed = dt + (elapsed if elapsed > GAP_PERIODS * PERIOD else 0.0)
        assert np.all(np.abs(vel - prev_vel) <= limiter.max_acceleration_rad_s2 * allowed + 1e-6)
    else:
        np.testing.assert_array_equal(pos, prev_pos)


@settings(max_examples=100, deadline=None, derandomize=True)  # reproducible in CI
@given(
    event_sequences(),
    st.sampled_from(["kalman", "lowpass", "none"]),
    st.sampled_from(["hold", "neutral"]),
)
def test_when_any_input_expect_every_command_finite_and_within_all_limits(
    robot, events, smoothing, stop_behaviour
):
    filt = MotionFilter(
        robot, MotionFilterSettings(smoothing=smoothing, stop_behaviour=stop_behaviour)
    )
    t, last_tick = 0.0, None
    prev_pos, prev_vel = filt.position_rad.copy(), filt.velocity_rad_s.copy()
    for kind, payload in events:
        if kind in ("pose", "message"):
            filt.push(np.array(payload, dtype=np.float64).reshape(-1, N_JOINTS), t)
        elif kind == "voice":
            filt.set_voice_active(payload, t)
        elif kind == "enable":
            filt.set_enabled(payload)
        elif kind == "stop":
            filt.set_stop(payload)
        elif kind in ("head", "offset"):
            setter = filt.set_head_target if kind == "head" else filt.set_head_offset
            with contextlib.suppress(InputError):
                setter({"HeadYaw": payload[0], "HeadPitch": payload[1]}, t)
        elif kind == "time":
            t += payload
        elif kind == "settings":
            style = {k: v for k, v in payload.items() if k in STYLE_FIELDS}
            filt.update_settings(
                dataclasses.replace(
                    filt.settings, **{k: v for k, v in payload.items() if k not in style}
                ),
                style=dataclasses.replace(filt.style.settings, **style),
            )
        elif kind == "restart":
            start = np.array(payload)
            if np.isfinite(start).all():
                filt.start_from(start)
                last_tick = None
                prev_pos, prev_vel = filt.position_rad.copy(), filt.velocity_rad_s.copy()
                # The start pose is the robot's pose clamped into the limits, at rest.
                assert np.all(np.isfinite(prev_pos))
                assert np.all(prev_vel == 0)
        if kind != "tick":
            continue
        t += PERIOD
        elapsed = PERIOD if last_tick is None else t - last_tick
        pos, vel = filt.tick(t)
        check_command(filt, pos, vel, prev_pos, prev_vel, elapsed)
        if last_tick is None or t > last_tick:
            last_tick = t
        prev_pos, prev_vel = pos.copy(), vel.copy()
    assert filt.status.faults == 0  # nothing here should have needed the health guard


@settings(max_examples=60, deadline=None, derandomize=True)
@given(st.lists(poses, min_size=1, max_size=40), st.sampled_from(["kalman", "lowpass", "none"]))
def test_when_any_values_pass_the_gate_expect_smoother_state_stays_finite(robot, rows, smoothing):
    filt = MotionFilter(robot, MotionFilterSettings(smoothing=smoothing))
    t = 0.0
    for row in rows:
        t += PERIOD
        filt.push(np.array([row]), t)
        filt.tick(t)
        assert filt._smoother is None or filt._smoother.is_finite()
        assert np.all(np.isfinite(filt.position_rad))


@settings(max_examples=200, deadline=None, derandomize=True)
@given(
    st.lists(
        st.tuples(
            st.sampled_from([0.0, 0.001, 0.01, 0.4, 0.6, 4.0, 6.0, 1e6, 1e9]),
            st.sampled_from([1.0, -1.0]),
        ),
        max_size=30,
    )
)
def test_when_any_stamps_arrive_expect_none_far_off_accepted_and_never_locked_out(offsets):
    check = StampCheck(max_future_s=0.5, max_age_s=5.0)
    now = 1e6
    for offset, sign in offsets:
        now += 0.01
        stamp = now + sign * offset
        if check.check(stamp, now) == "":
            assert -5.0 <= stamp - now <= 0.5
    now += 0.01
    # A message stamped now (or just after the newest one accepted, which is at most
    # max_future_s ahead) is always used: no stamp can lock later messages out.
    assert check.check(max(now, check.last_s + 1e-3), now) == ""

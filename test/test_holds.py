"""A stop or a disable in force ends only by a release published after it (motion.holds)."""

from audio2pose_ros.motion.holds import Hold
from audio2pose_ros.motion.state_file import FilterMemory

NOW = 1.7e9  # a wall-clock time (s since the epoch)


def test_when_no_hold_in_force_expect_any_release_counts():
    hold = Hold()
    assert not hold.in_force
    assert hold.release(NOW - 1e6)
    assert hold.since_s is None


def test_when_release_published_after_the_stop_expect_released():
    hold = Hold()
    hold.engage(NOW - 10.0, NOW)
    assert hold.in_force
    assert hold.release(NOW - 5.0)
    assert not hold.in_force


def test_when_release_published_before_the_stop_expect_ignored_and_stop_kept():
    """An older panel's latched stop: false, delivered after the stop, ends nothing."""
    hold = Hold()
    hold.engage(NOW - 10.0, NOW)
    assert not hold.release(NOW - 20.0)
    assert hold.since_s == NOW - 10.0


def test_when_release_published_at_the_same_time_as_the_stop_expect_ignored():
    hold = Hold()
    hold.engage(NOW - 10.0, NOW)
    assert not hold.release(NOW - 10.0)
    assert hold.in_force


def test_when_a_later_stop_arrives_expect_it_moves_the_time_and_an_older_one_does_not():
    hold = Hold()
    hold.engage(NOW - 10.0, NOW)
    hold.engage(NOW - 3.0, NOW)
    assert hold.since_s == NOW - 3.0
    hold.engage(NOW - 8.0, NOW)  # an older stop, delivered late
    assert hold.since_s == NOW - 3.0
    assert not hold.release(NOW - 5.0)  # after the first stop, before the second one


def test_when_stop_published_by_a_clock_ahead_expect_in_force_since_now():
    """A publisher whose clock runs ahead cannot pin the stop in the future."""
    hold = Hold()
    hold.engage(NOW + 3600.0, NOW)
    assert hold.since_s == NOW
    assert hold.release(NOW + 1.0)


def test_when_restored_expect_its_time_else_the_saving_time_else_none():
    assert Hold.restored(True, NOW - 10.0, NOW - 1.0).since_s == NOW - 10.0
    assert Hold.restored(True, None, NOW - 1.0).since_s == NOW - 1.0  # older files
    assert Hold.restored(False, NOW - 10.0, NOW - 1.0).since_s is None


def test_when_restored_stop_meets_release_latched_before_the_saving_expect_ignored():
    hold = Hold.restored(True, None, NOW - 1.0)
    assert not hold.release(NOW - 2.0)
    assert hold.release(NOW)


def test_when_a_state_file_kept_a_stop_and_a_disable_expect_both_in_force_from_their_times(robot):
    pose = tuple(float(v) for v in robot.neutral_rad)
    memory = FilterMemory(tuple(robot.names), pose, True, NOW, False, NOW - 5.0, NOW - 7.0)
    stop, disable = Hold.kept(memory)
    assert (stop.since_s, disable.since_s) == (NOW - 5.0, NOW - 7.0)
    stop, disable = Hold.kept(FilterMemory(tuple(robot.names), pose, False, NOW))
    assert not stop.in_force
    assert not disable.in_force
    assert not any(hold.in_force for hold in Hold.kept(None))

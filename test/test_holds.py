"""A stop or a disable in force ends only by a release published after it (motion.holds)."""

from audio2pose_ros.motion.holds import MAX_REMEMBERED, Hold, HoldDeliveries
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


OPERATOR, FLOODER = b"operator", b"flooder"


def test_when_both_readers_deliver_one_hold_expect_it_engaged_once():
    deliveries = HoldDeliveries()
    assert deliveries.take(OPERATOR, 7, NOW)
    assert not deliveries.take(OPERATOR, 7, NOW)
    assert deliveries.take(OPERATOR, 8, NOW + 1.0)  # the same publisher's next hold
    assert deliveries.engaged == 2


def test_when_other_publishers_released_after_the_hold_was_published_expect_it_engaged():
    """A flood of releases taken before the hold (another reader served first) ends nothing."""
    deliveries = HoldDeliveries()
    deliveries.released(FLOODER, NOW + 1.0)
    assert deliveries.take(OPERATOR, 1, NOW)
    assert deliveries.engaged == 1


def test_when_its_own_publisher_released_it_already_expect_the_hold_not_engaged_again():
    deliveries = HoldDeliveries()
    deliveries.released(OPERATOR, NOW + 1.0)
    assert not deliveries.take(OPERATOR, 1, NOW)
    assert deliveries.take(OPERATOR, 2, NOW + 2.0)  # a hold after the release
    assert deliveries.engaged == 1


def test_when_an_older_release_follows_a_newer_one_expect_the_newest_kept():
    deliveries = HoldDeliveries()
    deliveries.released(OPERATOR, NOW + 5.0)
    deliveries.released(OPERATOR, NOW + 1.0)
    assert not deliveries.take(OPERATOR, 1, NOW + 3.0)


def test_when_rclpy_names_no_publisher_expect_every_delivery_engaged():
    deliveries = HoldDeliveries()
    deliveries.released(None, NOW + 1.0)
    assert deliveries.take(None, None, NOW)
    assert deliveries.take(None, None, NOW)
    assert deliveries.take(OPERATOR, None, NOW)  # a publisher without sequence numbers
    assert deliveries.take(OPERATOR, None, NOW)
    assert deliveries.engaged == 4


def test_when_many_holds_and_publishers_come_expect_memory_bounded_oldest_forgotten():
    deliveries = HoldDeliveries()
    for i in range(3 * MAX_REMEMBERED):
        assert deliveries.take(OPERATOR, i, NOW + i)
        deliveries.released(bytes([i % 256, i // 256]), NOW + i)
    assert len(deliveries.taken) == MAX_REMEMBERED
    assert len(deliveries.released_s) == MAX_REMEMBERED
    assert not deliveries.take(OPERATOR, 3 * MAX_REMEMBERED - 1, NOW)  # the newest kept

"""The filter's memory across restarts (state file) and the stamp check of raw trajectories."""

import json
import os

import numpy as np
import pytest

from audio2pose_ros.errors import InputError
from audio2pose_ros.motion.state_file import (
    FilterMemory,
    StateFileInUseError,
    StateLock,
    default_state_path,
    load_memory,
    save_memory,
)
from audio2pose_ros.motion.timing import StampCheck


def memory_of(robot, stopped=False, enabled=True):
    pose = robot.neutral_rad + 0.1
    return FilterMemory(tuple(robot.names), tuple(float(v) for v in pose), stopped, 1.0e9, enabled)


def test_when_saved_and_loaded_expect_same_pose_and_stop(tmp_path, robot):
    path = tmp_path / "deep" / "state.json"
    save_memory(path, memory_of(robot, stopped=True))
    assert load_memory(path, robot) == memory_of(robot, stopped=True)
    assert [p.name for p in path.parent.iterdir()] == ["state.json"]  # no temporary left over


def test_when_saved_disabled_expect_it_loaded_disabled(tmp_path, robot):
    path = tmp_path / "state.json"
    save_memory(path, memory_of(robot, enabled=False))
    loaded = load_memory(path, robot)
    assert loaded is not None
    assert loaded.enabled is False
    assert loaded == memory_of(robot, enabled=False)


def test_when_file_predates_enable_expect_enabled(tmp_path, robot):
    """State files written before 'enabled' was kept still load: enabled, as they behaved."""
    path = tmp_path / "state.json"
    save_memory(path, memory_of(robot, stopped=True))
    data = json.loads(path.read_text())
    del data["enabled"]
    path.write_text(json.dumps(data))
    assert load_memory(path, robot) == memory_of(robot, stopped=True, enabled=True)


@pytest.mark.parametrize("value", [0, "false", None, [False]])
def test_when_enabled_is_not_true_or_false_expect_refused(tmp_path, robot, value):
    path = tmp_path / "state.json"
    save_memory(path, memory_of(robot))
    data = json.loads(path.read_text())
    data["enabled"] = value
    path.write_text(json.dumps(data))
    with pytest.raises(InputError, match="'enabled' must be true/false"):
        load_memory(path, robot)


def test_when_no_file_expect_none(tmp_path, robot):
    assert load_memory(tmp_path / "missing.json", robot) is None


@pytest.mark.parametrize(
    ("content", "problem"),
    [
        ("{not json", "not a JSON filter state"),
        ("[1, 2]", "not a filter state file"),
        ("[" * 100_000, "larger than"),
        ("[" * 60_000, "not a JSON filter state"),  # nesting deeper than the parser's stack
        (json.dumps({"format": 1, "joint_names": ["a"], "position_rad": [0.0]}), "joints"),
    ],
)
def test_when_file_is_damaged_or_foreign_expect_input_error_naming_it(
    tmp_path, robot, content, problem
):
    path = tmp_path / "state.json"
    path.write_text(content)
    with pytest.raises(InputError, match=problem):
        load_memory(path, robot)


def test_when_saved_angles_not_finite_expect_refused(tmp_path, robot):
    path = tmp_path / "state.json"
    save_memory(path, memory_of(robot))
    data = json.loads(path.read_text())
    data["position_rad"][3] = float("nan")
    path.write_text(json.dumps(data))
    with pytest.raises(InputError, match="finite angles"):
        load_memory(path, robot)


def test_when_ros_home_set_expect_state_under_it(monkeypatch, tmp_path):
    monkeypatch.setenv("ROS_HOME", str(tmp_path))
    monkeypatch.setenv("ROS_DOMAIN_ID", "7")
    expected = tmp_path / "audio2pose_ros" / "domain_7" / "robot1__motion_filter_node.json"
    assert default_state_path("/robot1/motion_filter_node") == expected


def test_when_two_robots_differ_in_domain_or_namespace_expect_different_files(monkeypatch):
    """Two graphs of one user must not share a state file (one's stop lost by the other)."""
    monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
    paths = {
        default_state_path("/motion_filter_node", "1"),
        default_state_path("/motion_filter_node", "2"),
        default_state_path("/pepper1/motion_filter_node", "1"),
        default_state_path("/motion_filter_node"),
    }
    assert len(paths) == 4


def test_when_a_second_owner_takes_the_state_file_expect_refused_naming_the_file(tmp_path):
    path = tmp_path / "state.json"
    first = StateLock(path)
    with pytest.raises(StateFileInUseError, match=f"{path}.*pid {os.getpid()}"):
        StateLock(path)
    first.release()
    StateLock(path).release()  # free again once the owner is gone


def test_when_saved_pose_outside_range_expect_it_refused_not_clamped(robot):
    pose = list(robot.neutral_rad)
    pose[robot.names.index("LShoulderPitch")] = (
        robot.upper_rad[robot.names.index("LShoulderPitch")] + 0.5
    )
    memory = FilterMemory(tuple(robot.names), tuple(pose), False, 1.0)
    assert not memory.pose_in_range(robot)
    assert memory_of(robot).pose_in_range(robot)


def test_when_one_stamp_is_far_in_the_future_expect_it_rejected_and_later_ones_accepted():
    check = StampCheck(max_future_s=0.5, max_age_s=5.0)
    now = 1000.0
    assert check.check(now, now) == ""
    assert "ahead of the node clock" in check.check(now + 1e6, now + 0.01)
    for i in range(1, 10):  # the next messages are not taken for late ones
        assert check.check(now + 0.01 * i, now + 0.01 * i + 0.002) == ""
    assert check.counts.future == 1
    assert check.counts.out_of_order == 0


def test_when_the_clock_steps_back_expect_stamps_on_the_new_clock_accepted_at_once():
    """An NTP step moves the node's clock and the sender's stamps back together."""
    check = StampCheck(max_future_s=0.5, max_age_s=5.0)
    for k in range(100):
        now = 1000.0 + k * 0.01
        assert check.check(now, now) == ""
    accepted = [check.check(940.0 + k * 0.01, 940.0 + k * 0.01) == "" for k in range(100)]
    assert all(accepted)  # not dropped as out of order until the clock catches up
    assert check.counts.clock_steps_back == 1
    assert check.counts.out_of_order == 0
    # a message from before the step, delivered late, is still refused: ahead of the clock
    assert "ahead of the node clock" in check.check(1000.5, 941.0)


def test_when_stamps_old_duplicated_or_unset_expect_each_handled():
    check = StampCheck(max_future_s=0.5, max_age_s=5.0)
    assert "behind the node clock" in check.check(10.0, 100.0)
    assert check.check(99.0, 100.0) == ""
    assert "out-of-order" in check.check(99.0, 100.0)
    assert check.check(0.0, 100.0) == ""  # unstamped: accepted, does not move the order
    assert (check.counts.too_old, check.counts.out_of_order) == (1, 1)
    assert np.isclose(check.latency_s, 1.0)

"""The node's use of its state file (motion.state_file.StateStore): what it reports at start."""

import math

from audio2pose_ros.motion.state_file import FilterMemory, StateStore, save_memory


def test_when_the_file_is_fine_expect_no_problem(tmp_path, robot):
    path = tmp_path / "state.json"
    pose = tuple(float(v) for v in robot.neutral_rad)
    save_memory(path, FilterMemory(tuple(robot.names), pose, False, 1.0e9))
    store = StateStore(path, robot)
    assert store.problems() == []
    store.lock.release()


def test_when_the_file_is_damaged_expect_a_warn_saying_it_is_ignored(tmp_path, robot):
    path = tmp_path / "state.json"
    path.write_text("{not json")
    store = StateStore(path, robot)
    [problem] = store.problems()
    assert (problem.key, problem.error) == ("state_file", False)
    assert problem.text.startswith("state file ignored: ")
    store.lock.release()


def test_when_the_saved_pose_is_out_of_range_expect_a_warn_naming_the_file(tmp_path, robot):
    path = tmp_path / "state.json"
    pose = tuple(float(v) for v in robot.upper_rad + 0.5)
    save_memory(path, FilterMemory(tuple(robot.names), pose, True, 1.0e9))
    store = StateStore(path, robot)
    [problem] = store.problems()
    assert (problem.key, problem.error, problem.hold_s) == ("saved_pose_refused", False, 10.0)
    assert str(path) in problem.text
    assert store.saved_pose() is None
    store.lock.release()


def test_when_the_state_cannot_be_saved_expect_an_error_until_a_save_succeeds(tmp_path, robot):
    store = StateStore(tmp_path / "state.json", robot)
    stopped = store.unsaved("cannot be written: disk full", stopped=True)
    assert (stopped.key, stopped.error, stopped.hold_s) == ("state_file_unsaved", True, math.inf)
    assert "The STOP in force stays in force" in stopped.text
    assert "A stop stays" in store.unsaved("cannot be written", stopped=False).text
    store.lock.release()

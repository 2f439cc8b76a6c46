"""Independent tasks run in worker processes come back in order, failures included."""

from functools import partial

import pytest

from audio2pose_ros.learning.parallel import default_workers, run_tasks


def test_when_running_in_two_processes_expect_the_results_in_task_order():
    tasks = [partial(pow, 2, n) for n in range(5)]
    assert run_tasks(tasks, workers=2) == [1, 2, 4, 8, 16] == run_tasks(tasks)


def test_when_a_worker_task_fails_expect_its_exception_here():
    with pytest.raises(ValueError, match="invalid literal"):
        run_tasks([partial(pow, 2, 3), partial(int, "x")], workers=2)


def test_when_asked_for_no_workers_expect_an_error():
    with pytest.raises(ValueError, match="at least 1"):
        run_tasks([partial(pow, 2, 3)], workers=0)
    assert default_workers() >= 1

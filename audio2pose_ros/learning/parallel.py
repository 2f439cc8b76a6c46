"""Independent trainings side by side, one process per core (the default model's rebuild).

The models are small recurrent networks trained on batches of a few windows: a GRU step is a
product of a few dozen rows, too small for torch's threads to share, so one training keeps
about one core busy whatever its thread count. Leave-one-speaker-out folds and
cross-validation models are independent, so :func:`run_tasks` runs them in worker processes,
each training with one thread. Workers are spawned (not forked: a fork of a process whose torch
thread pool has started can deadlock) and take their tasks in order; results come back in the
order of the tasks, so a rebuild gives the same result with one worker or several, up to
floating-point summation order.
"""

from __future__ import annotations

import multiprocessing
import os
import sys
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import TypeVar

T = TypeVar("T")


def default_workers() -> int:
    """The cores this process may use (at least 1)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


def report(message: str) -> None:
    """Print one progress line to standard error (module-level, so workers can be given it)."""
    print(message, file=sys.stderr, flush=True)


def _one_thread() -> None:
    import torch

    torch.set_num_threads(1)


def run_tasks(tasks: Sequence[Callable[[], T]], workers: int = 1) -> list[T]:
    """Run picklable callables (e.g. ``functools.partial`` of module-level functions).

    Args:
        tasks: the work, each independent of the others.
        workers: processes; 1 (or a single task) runs them here, in order.

    Returns:
        Each task's result, in the order of ``tasks``.

    Raises:
        ValueError: ``workers`` below 1.
        Exception: the first failing task's exception, as the task raised it.

    """
    if workers < 1:
        raise ValueError(f"workers must be at least 1, got {workers}")
    if workers == 1 or len(tasks) < 2:
        return [task() for task in tasks]
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(
        max_workers=min(workers, len(tasks)), mp_context=context, initializer=_one_thread
    ) as pool:
        futures = [pool.submit(task) for task in tasks]
        return [future.result() for future in futures]

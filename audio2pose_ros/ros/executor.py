"""The executor a node process spins in: the stock SingleThreadedExecutor, or EventsExecutor opt-in.

Every node runs in rclpy's stock SingleThreadedExecutor (the one ``rclpy.spin`` uses, on every
distro). ``AUDIO2POSE_EXECUTOR=events`` chooses rclpy's experimental EventsExecutor instead,
where rclpy has one (``rclpy.experimental``, Jazzy and later; Humble keeps the
SingleThreadedExecutor): it is opt-in, never required, and nothing in a node depends on it or on
the order in which either executor serves callbacks. The timers safety depends on are
:class:`~audio2pose_ros.ros.paced_timer.PacedTimer`, which no backlog holds back by more than one
callback in either. Under the EventsExecutor the subscriptions are message-only: Kilted's
(rclpy 9.1) fails inside its ``spin_once`` on a callback that takes a message and its info, so
the nodes use there what they use on Humble, whose executors pass no info
(:mod:`audio2pose_ros.ros.subscriptions`). Also here: :func:`shutdown`, the end of an rclpy
context on every distro.
"""

from __future__ import annotations

import os

import rclpy
from rclpy.context import Context
from rclpy.executors import Executor, SingleThreadedExecutor

EXECUTOR_ENV = "AUDIO2POSE_EXECUTOR"  # "events" for the EventsExecutor; anything else: stock
EVENTS = "events"


def events_executor_requested() -> bool:
    """Whether ``AUDIO2POSE_EXECUTOR=events`` asks for rclpy's EventsExecutor."""
    return os.environ.get(EXECUTOR_ENV, "") == EVENTS


def create_executor() -> Executor:
    """A SingleThreadedExecutor, or the EventsExecutor when requested and this rclpy has one."""
    if events_executor_requested():
        try:
            from rclpy.experimental.events_executor import EventsExecutor
        except ImportError:  # Humble: no EventsExecutor, the stock executor serves as well
            pass
        else:
            return EventsExecutor()
    return SingleThreadedExecutor()


def shutdown(context: Context | None = None) -> None:
    """Shut rclpy's ``context`` (default: the global one) down, unless it is down already.

    ``rclpy.try_shutdown`` where rclpy has it (Jazzy, Kilted); Humble has only
    ``rclpy.shutdown``, which raises on a context already shut down (by Ctrl-C, say).
    """

    def ok() -> bool:
        return context.ok() if context is not None else rclpy.ok()

    try_shutdown = getattr(rclpy, "try_shutdown", None)
    try:
        if try_shutdown is not None:
            try_shutdown(context=context)
        elif ok():
            rclpy.shutdown(context=context)
    except RuntimeError:
        if ok():  # not shut down meanwhile by rclpy's signal handler (a race Jazzy's loses)
            raise

"""A rclpy node beside a graph under test: its own context, spun by a thread of its own.

The browser and console tests watch or drive the graph while the test's own thread waits on a
page; this node answers meanwhile. Subclasses create their publishers, subscriptions and timers
on ``self.node`` and then call :meth:`start`. :class:`ParameterReader` is one: it reads another
node's parameters over its get_parameters service. :func:`spinning` serves a node of the test's
own session (a console under test) the same way.
"""

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any


@contextmanager
def spinning(node: Any, executor: Any) -> Iterator[None]:
    """Spin ``node`` with ``executor`` from a thread of its own; destroy it after.

    Served as the node's process serves it (the project's ``spin_once``: overdue paced timers
    run between callbacks), while the test's thread drives and waits.
    """
    from audio2pose_ros.ros.spin import spin_once

    executor.add_node(node)
    stopping = threading.Event()

    def spin() -> None:
        while not stopping.is_set():
            spin_once(executor, [node], 0.05)

    thread = threading.Thread(target=spin, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stopping.set()
        thread.join(timeout=10.0)
        executor.remove_node(node)
        node.destroy_node()


class BackgroundNode:
    def __init__(self, name: str) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node

        self.context = Context()
        rclpy.init(context=self.context)
        self.node = Node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.stopping = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)

    def start(self) -> None:
        self.thread.start()

    def _spin(self) -> None:
        while not self.stopping.is_set():
            self.executor.spin_once(timeout_sec=0.1)

    def close(self) -> None:
        import rclpy

        self.stopping.set()
        self.thread.join(timeout=2.0)
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


class ParameterReader(BackgroundNode):
    """Reads another node's parameters through its get_parameters service."""

    def __init__(self, node_name: str) -> None:
        from rcl_interfaces.srv import GetParameters

        super().__init__(f"parameter_reader_{node_name.strip('/').replace('/', '_')}")
        self.request = GetParameters.Request
        self.client = self.node.create_client(GetParameters, f"/{node_name}/get_parameters")
        self.start()

    def read(self, name: str) -> object:
        """The parameter ``name`` as a Python value; None while the service does not answer."""
        from rclpy.parameter import parameter_value_to_python

        if not self.client.wait_for_service(timeout_sec=1.0):
            return None
        future = self.client.call_async(self.request(names=[name]))
        deadline = time.monotonic() + 5.0
        while not future.done() and time.monotonic() < deadline:
            time.sleep(0.01)
        values = future.result().values if future.done() and future.result() else []
        return parameter_value_to_python(values[0]) if values else None

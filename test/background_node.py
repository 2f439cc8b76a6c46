"""A rclpy node beside a graph under test: its own context, spun by a thread of its own.

The browser and console tests watch or drive the graph while the test's own thread waits on a
page; this node answers meanwhile. Subclasses create their publishers, subscriptions and timers
on ``self.node`` and then call :meth:`start`.
"""

import threading


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

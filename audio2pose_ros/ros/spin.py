"""How a node process runs: its executor, the spin, and main() for one node or several.

Every node executable's ``main`` calls :func:`run_node` (or :func:`run_nodes` for several nodes
in one process): rclpy's init, the nodes built with their configuration checked (a refusal ends
the process with exit status 78, never respawned), the executor of
:func:`~audio2pose_ros.ros.executor.create_executor` spun by :func:`spin_executor` until Ctrl-C or
SIGTERM.
"""

from __future__ import annotations

import faulthandler
import signal
import sys
import time
from collections.abc import Callable, Sequence
from typing import NoReturn

import rclpy
from rclpy.executors import Executor, ExternalShutdownException
from rclpy.node import Node

from audio2pose_ros.errors import EXIT_CONFIGURATION_ERROR, ConfigurationError
from audio2pose_ros.ros.diagnosed_node import DiagnosedNode
from audio2pose_ros.ros.executor import create_executor, shutdown
from audio2pose_ros.ros.nodes.process import STOP_SIGNALS
from audio2pose_ros.ros.supervisor_pipe import STACK_DUMP_SIGNAL, to_terminal

SPIN_ONCE_TIMEOUT_S = 0.5  # an idle executor checks for shutdown this often


def spin_executor(executor: Executor, nodes: Sequence[Node] = ()) -> None:
    """Spin until the context shuts down (Ctrl-C, SIGTERM, ``rclpy.shutdown``).

    One round at a time (:func:`spin_once`), after which the overdue paced timers of ``nodes``
    run: the same loop for either executor (:mod:`audio2pose_ros.ros.executor`), whatever
    order it serves callbacks in.
    """
    paced = [node for node in nodes if isinstance(node, DiagnosedNode) and node.paced_timers]
    while executor.context.ok():
        spin_once(executor, paced)


def spin_once(
    executor: Executor, nodes: Sequence[Node], timeout_s: float = SPIN_ONCE_TIMEOUT_S
) -> None:
    """Serve one callback (or wait ``timeout_s`` for one), then run the overdue paced timers.

    Between two callbacks, the :class:`~audio2pose_ros.ros.paced_timer.PacedTimer` of ``nodes``
    that are overdue run, so no backlog of messages holds them back by more than one callback
    (a guarded callback runs them too).
    """
    executor.spin_once(timeout_sec=timeout_s)
    now = time.monotonic()
    for node in nodes:
        if isinstance(node, DiagnosedNode):
            node.run_overdue_timers(now)


def _refused(line: str) -> NoReturn:
    """End the process for a refused configuration: ``line`` on stderr and the terminal, exit 78."""
    print(line, file=sys.stderr, flush=True)
    to_terminal(line)
    raise SystemExit(EXIT_CONFIGURATION_ERROR) from None


def init(args: list[str] | None, process_name: str) -> None:
    """Rclpy's init; arguments rcl cannot parse end the process (:func:`_refused`).

    rcl refuses them (a parameters file with a YAML syntax error, a missing file) with its
    ``RCLError``, which rclpy does not export: a RuntimeError here, and only from this call.
    Not ``with rclpy.init()``: Humble's init is no context manager.
    """
    try:
        rclpy.init(args=args)
    except RuntimeError as exc:
        refused = " ".join(str(exc).split())
        _refused(f"[{process_name}] configuration error: ROS arguments refused: {refused}")


def run_node(factory: Callable[[], Node], node_name: str, args: list[str] | None = None) -> None:
    """The ros2/examples main for one node: see :func:`run_nodes`."""
    run_nodes([factory], node_name, args)


def run_nodes(
    factories: Sequence[Callable[[], Node]],
    process_name: str,
    args: list[str] | None = None,
    connect: Callable[[list[Node]], None] | None = None,
) -> None:
    """Init, build the nodes, spin them in one executor until Ctrl-C / SIGTERM, clean up.

    One factory is the usual one node per process; several put nodes in one process and one
    executor (``audio2pose run --single-process``), where ``connect`` (called with the built
    nodes, in order, before spinning) wires them to each other. A
    :class:`~audio2pose_ros.errors.ConfigurationError` while a node is built (a refused
    parameter, a bad model or robot file), or arguments rcl cannot parse (a parameters file with
    a YAML syntax error, a missing file), end the process with one line on stderr (and on the
    user's terminal when stderr goes to a log: :func:`to_terminal`) and exit status
    :data:`EXIT_CONFIGURATION_ERROR`, which ``audio2pose run`` and the launch file never respawn.
    """
    try:
        # Ctrl-C or SIGTERM while rcl initialises or the nodes are built would shut the context
        # down under them: the signals wait until the nodes are ready (the node executables
        # block them from their first line, nodes.process), then rclpy's handler ends the spin.
        signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
        # A supervisor about to kill a silent process first asks for every thread's stack
        # (written to stderr, the node's log), so a silent node says where it was stuck.
        faulthandler.register(STACK_DUMP_SIGNAL, all_threads=True)
        try:
            init(args, process_name)
            executor = create_executor()
            nodes = [factory() for factory in factories]
            if connect is not None:
                connect(nodes)
            for node in nodes:
                executor.add_node(node)
            signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
            spin_executor(executor, nodes)
        finally:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
            shutdown()
    except ConfigurationError as exc:
        _refused(f"[{process_name}] configuration error: {exc}")
    except (KeyboardInterrupt, ExternalShutdownException):
        pass

"""How a node process runs: its executor, the spin, and main() for one node or several.

Every node executable's ``main`` calls :func:`run_node` (or :func:`run_nodes` for several nodes
in one process): rclpy's init, the nodes built with their configuration checked (a refusal ends
the process with exit status 78, never respawned), the executor of :func:`create_executor` spun
by :func:`spin_executor` until Ctrl-C or SIGTERM.
"""

from __future__ import annotations

import faulthandler
import os
import signal
import sys
import time
from collections.abc import Callable, Sequence
from typing import NoReturn

import rclpy
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.node import Node

from audio2pose_ros.errors import EXIT_CONFIGURATION_ERROR, ConfigurationError
from audio2pose_ros.ros.diagnosed_node import STACK_DUMP_SIGNAL, DiagnosedNode, to_terminal
from audio2pose_ros.ros.nodes.process import STOP_SIGNALS

SPIN_ONCE_TIMEOUT_S = 0.5  # an idle EventsExecutor checks for shutdown this often
EXECUTOR_ENV = "AUDIO2POSE_EXECUTOR"  # "events" (default where available) or "single_threaded"


def create_executor() -> Executor:
    """The executor the nodes spin in: rclpy's EventsExecutor where available, else single-threaded.

    The EventsExecutor (``rclpy.experimental``, Jazzy and later) is driven by middleware events
    instead of rebuilding a wait set in Python for every callback, which was the largest single
    item of the nodes' CPU (20-40 % of each node's samples under traffic); with it the
    three nodes used 2.9 instead of 4.2 ms CPU per 10 ms frame. Humble has none and gets the
    SingleThreadedExecutor; ``AUDIO2POSE_EXECUTOR=single_threaded`` forces it (for comparison,
    or should a distro's EventsExecutor misbehave). Spin it with :func:`spin_executor`.

    Every node runs correctly in either. The EventsExecutor serves events first come, first
    served, so a flood on one topic would delay a timer by the whole backlog: the timers a
    node's safety depends on (the heartbeat, the motion filter's command tick and start-up
    decision) are :class:`~audio2pose_ros.ros.diagnosed_node.PacedTimer`, run between events
    when overdue. It ignores callback groups and serves every waiting service request back to
    back: the motion filter serves its parameter services itself, one request per tick
    (:class:`~audio2pose_ros.ros.request_budget.RequestBudget`). It hands a subscription's
    MessageInfo as one tuple with the message, which
    :meth:`~audio2pose_ros.ros.diagnosed_node.DiagnosedNode.create_bounded_subscription` unpacks.
    """
    if os.environ.get(EXECUTOR_ENV, "events") != "single_threaded":
        try:
            from rclpy.experimental.events_executor import EventsExecutor
        except ImportError:  # Humble
            pass
        else:
            return EventsExecutor()
    return SingleThreadedExecutor()


def spin_executor(executor: Executor, nodes: Sequence[Node] = ()) -> None:
    """Spin until the context shuts down (Ctrl-C, SIGTERM, ``rclpy.shutdown``).

    The EventsExecutor is spun one event at a time (:func:`spin_once`): its ``spin()`` (rclpy
    9.1) never ran a callback here, while ``spin_once`` serves timers and subscriptions as
    expected. The SingleThreadedExecutor spins as rclpy spins it: each round of its wait set
    serves every ready timer.
    """
    if isinstance(executor, SingleThreadedExecutor):
        executor.spin()
        return
    paced = [node for node in nodes if isinstance(node, DiagnosedNode) and node.paced_timers]
    while executor.context.ok():
        spin_once(executor, paced)


def spin_once(
    executor: Executor, nodes: Sequence[Node], timeout_s: float = SPIN_ONCE_TIMEOUT_S
) -> None:
    """Serve one event (or wait ``timeout_s`` for one), then run the overdue paced timers.

    Between two events, the :class:`~audio2pose_ros.ros.diagnosed_node.PacedTimer` of
    ``nodes`` that are overdue run, so no backlog of messages holds them back by more than one
    message (a guarded callback runs them too, after each message of an event that brings
    several).
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
            rclpy.init(args=args)  # not `with rclpy.init()`: Humble's init is no context manager
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
            rclpy.try_shutdown()
    except ConfigurationError as exc:
        _refused(f"[{process_name}] configuration error: {exc}")
    except rclpy_implementation.RCLError as exc:
        refused = " ".join(str(exc).split())
        _refused(f"[{process_name}] configuration error: ROS arguments refused: {refused}")
    except (KeyboardInterrupt, ExternalShutdownException):
        pass

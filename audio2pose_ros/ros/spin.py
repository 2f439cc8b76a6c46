"""How a node process runs: its executor, the spin, and main() for one node or several.

Every node executable's ``main`` calls :func:`run_node` (or :func:`run_nodes` for several nodes
in one process): rclpy's init, the nodes built with their configuration checked (a refusal ends
the process with exit status 78, never respawned), the executor of
:func:`~audio2pose_ros.ros.executor.create_executor` spun by :func:`spin_executor` until Ctrl-C or
SIGTERM, then everything closed in order (:func:`close`).
"""

from __future__ import annotations

import faulthandler
import signal
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any, NoReturn

import rclpy
from rclpy.executors import Executor, ExternalShutdownException
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from audio2pose_ros.errors import EXIT_CONFIGURATION_ERROR, ConfigurationError
from audio2pose_ros.ros.diagnosed_node import DiagnosedNode
from audio2pose_ros.ros.executor import create_executor, shutdown
from audio2pose_ros.ros.nodes.process import STOP_SIGNALS
from audio2pose_ros.ros.supervisor_pipe import STACK_DUMP_SIGNAL, to_terminal

SPIN_ONCE_TIMEOUT_S = 0.5  # an idle executor checks for shutdown this often


def spin_executor(
    executor: Executor, nodes: Sequence[Node] = (), until: Callable[[], bool] | None = None
) -> None:
    """Spin until the context shuts down or ``until()`` says so (a stop signal: :class:`Stop`).

    One round at a time (:func:`spin_once`), after which the overdue paced timers of ``nodes``
    run: the same loop for either executor (:mod:`audio2pose_ros.ros.executor`), whatever
    order it serves callbacks in.
    """
    paced = [node for node in nodes if isinstance(node, DiagnosedNode) and node.paced_timers]
    while executor.context.ok() and not (until is not None and until()):
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
    """Rclpy's init, without its signal handlers (:class:`Stop` takes the signals).

    Arguments rcl cannot parse end the process (:func:`_refused`): rcl refuses them (a
    parameters file with a YAML syntax error, a missing file) with its ``RCLError``, which rclpy
    does not export: a RuntimeError here, and only from this call. Not ``with rclpy.init()``:
    Humble's init is no context manager.
    """
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except RuntimeError as exc:
        refused = " ".join(str(exc).split())
        _refused(f"[{process_name}] configuration error: ROS arguments refused: {refused}")


class Stop:
    """SIGINT and SIGTERM, taken by the process's main thread and kept for its spin to end.

    rclpy's own handlers shut the context down on a thread of their own, while the main thread
    may be destroying the nodes (Jazzy's middleware then crashed, SIGSEGV in a subscription's
    destruction), and raise KeyboardInterrupt in the middle of any callback. A node process
    initialises rclpy without them (``SignalHandlerOptions.NO``, on every distro) and takes the
    signals here instead: the first is kept, the spin ends after the callback it interrupted
    (within :data:`SPIN_ONCE_TIMEOUT_S` when idle), and the nodes are destroyed before the context
    shuts down (:func:`close`); a second one leaves at once, as a shell's job would.
    """

    def __init__(self) -> None:
        self.signum: int | None = None
        self._before: dict[int, Any] = {}

    def requested(self) -> bool:
        """Whether a stop signal came."""
        return self.signum is not None

    def _take(self, signum: int, _frame: object) -> None:
        if self.signum is not None:
            raise SystemExit(128 + signum)
        self.signum = signum

    def __enter__(self) -> Stop:
        for signum in STOP_SIGNALS:
            self._before[signum] = signal.signal(signum, self._take)
        return self

    def __exit__(self, *_exc: object) -> None:
        for signum, handler in self._before.items():
            signal.signal(signum, handler)

    def exit_status(self) -> None:
        """Leave as a shell reports SIGTERM (143); Ctrl-C is the usual stop, status 0."""
        if self.signum == signal.SIGTERM:
            raise SystemExit(128 + signal.SIGTERM)


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
    executor: Executor | None = None
    nodes: list[Node] = []
    # Ctrl-C or SIGTERM while rcl initialises or the nodes are built wait until the nodes are
    # ready (the node executables block them from their first line, nodes.process); then
    # :class:`Stop` takes them and the spin ends
    signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    # A supervisor about to kill a silent process first asks for every thread's stack (written
    # to stderr, the node's log), so a silent node says where it was stuck; a crash (a fault in
    # a library) writes them there too.
    faulthandler.register(STACK_DUMP_SIGNAL, all_threads=True)
    faulthandler.enable(all_threads=True)
    with Stop() as stop:
        try:
            try:
                init(args, process_name)
                executor = create_executor()
                for factory in factories:
                    nodes.append(factory())
                if connect is not None:
                    connect(nodes)
                for node in nodes:
                    executor.add_node(node)
                signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
                spin_executor(executor, nodes, stop.requested)
            finally:
                signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
                close(executor, nodes)
        except ConfigurationError as exc:
            _refused(f"[{process_name}] configuration error: {exc}")
        except ExternalShutdownException:
            pass
        stop.exit_status()


def close(executor: Executor | None, nodes: Sequence[Node]) -> None:
    """End a node process in order, leaving nothing to the interpreter's exit.

    The executor first, then the nodes in the reverse of their building (each ends its own
    threads and writes what it keeps: its ``destroy_node``), then the context: Jazzy's
    middleware crashes when an entity is destroyed after its context shut down (SIGSEGV in a
    subscription's destruction, in 1 or 2 of 8 stops during start-up, and at the interpreter's
    exit now and then).
    """
    if executor is not None:
        executor.shutdown()
    for node in reversed(nodes):
        node.destroy_node()
    shutdown()

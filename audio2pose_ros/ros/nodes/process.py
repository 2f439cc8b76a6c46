"""Entry points of the node executables: make the process safe to start and stop, then import.

The console scripts ``audio_features_node``, ``inference_node`` and ``motion_filter_node`` start
here, before any heavy import (rclpy, numpy, torch take seconds), so that from the first
instant of the process:

- it dies with its parent: ``PR_SET_PDEATHSIG`` (Linux) makes the kernel send SIGTERM when the
  process that started it (``ros2 launch``, ``audio2pose run``) ends in any way, even SIGKILL, so
  nodes are never left running as orphans; a process whose parent is already gone exits at once;
- SIGTERM and Ctrl-C (SIGINT) end it quietly at any point of start-up: they are blocked from
  here until the nodes are built (:func:`~audio2pose_ros.ros.spin.run_nodes`), then
  delivered to the main thread only, where :class:`~audio2pose_ros.ros.spin.Stop` ends the spin
  and the nodes are destroyed before the context shuts down. Threads started meanwhile
  (numpy's, the middleware's) inherit the block, so a signal never runs a handler on another
  thread while the main one is creating nodes (rclpy's own handlers, which shut the context down
  under them, ended a node with a configuration error, and once with SIGABRT).

Then (:func:`lighten_node_imports`) it imports its node module

- without the message code generator that every generated message module would load
  (:func:`defer_message_code_generator`);
- with its URDF parsed in a child process (:func:`~audio2pose_ros.robot.urdf_outline.parse_apart`:
  the parser's XML library would stay mapped for the life of the node, 4.2 MB, to read one file
  at start);
- with ``hashlib`` on CPython's own hash functions, not OpenSSL's (:func:`use_builtin_hashes`).
"""

from __future__ import annotations

import ctypes
import importlib
import importlib.util
import os
import signal
import sys
from typing import Any

from audio2pose_ros.robot import urdf_outline

__all__ = [
    "audio_features_node",
    "console_node",
    "defer_message_code_generator",
    "inference_node",
    "lighten_node_imports",
    "motion_filter_node",
    "pepper_sim_node",
    "prepare_node_process",
    "use_builtin_hashes",
    "voice_out_node",
]

PR_SET_PDEATHSIG = 1  # linux/prctl.h
STOP_SIGNALS = frozenset({signal.SIGINT, signal.SIGTERM})


def _exit_on_signal(signum: int, _frame: object) -> None:
    """A termination signal before rclpy took over: leave as a shell would report it."""
    raise SystemExit(128 + signum)


def prepare_node_process() -> None:
    """Die with the parent process and exit cleanly on SIGTERM; call first thing in a node."""
    signal.signal(signal.SIGTERM, _exit_on_signal)
    # A parent may start us with SIGINT ignored (a shell's background job): Ctrl-C must work.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    parent = os.getppid()
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
        except (OSError, AttributeError):  # no prctl (not glibc): orphans are the launcher's job
            pass
    if parent == 1 or os.getppid() != parent:  # the parent died before prctl took effect
        raise SystemExit(128 + signal.SIGTERM)


def defer_message_code_generator() -> None:
    """Let message modules import ``rosidl_generator_py`` without its code generator.

    Every generated message module (ROS 2 Jazzy and later; Humble's too) imports
    ``import_type_support`` from the package ``rosidl_generator_py``, whose ``__init__`` also
    imports ``generate_py``, the build-time generator of message code: the ``lark`` grammar
    of rosidl_parser, ``empy`` and ``hashlib`` with OpenSSL. A node never generates code,
    and those hold 3 to 6.5 MB of each node process (6.5 where nothing else loads OpenSSL, as
    in ``motion_filter_node``). Here the package is entered with ``import_type_support``
    alone; its ``__init__`` runs as usual the first time anything asks the package for another
    name (a module ``__getattr__``, PEP 562). Does nothing if the package is already imported
    or not installed.
    """
    name = "rosidl_generator_py"
    if name in sys.modules:
        return
    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError):
        return
    if spec is None or spec.loader is None or spec.submodule_search_locations is None:
        return
    package = importlib.util.module_from_spec(spec)
    sys.modules[name] = package
    try:
        impl = importlib.import_module(f"{name}.import_type_support_impl")
    except ImportError:  # another layout: the package as it is
        del sys.modules[name]
        return
    loader = spec.loader

    def whole_package(attribute: str) -> Any:
        """Run the package's own ``__init__`` (once) and return its ``attribute``."""
        del names["__getattr__"]
        loader.exec_module(package)
        return getattr(package, attribute)

    names = vars(package)
    names["import_type_support"] = impl.import_type_support
    names["__getattr__"] = whole_package


def use_builtin_hashes() -> None:
    """Make ``hashlib`` use CPython's own hash functions: OpenSSL's libcrypto stays unloaded.

    ``hashlib`` imports ``_hashlib``, OpenSSL's hashes, whenever it is imported: 3.6 MB of
    resident memory in a node that verifies one checkpoint digest at start and imports
    ``numpy.random``, whose ``secrets`` imports ``hmac`` and so ``hashlib``. Without
    ``_hashlib``, ``hashlib`` falls back on CPython's own MD5, SHA-1, SHA-2, SHA-3 and BLAKE2
    (its documented behaviour on a build without OpenSSL): the same digests, at a speed that is
    no concern for a 60 KB checkpoint. Nothing in a node uses what only OpenSSL has
    (``pbkdf2_hmac``, ``scrypt``, other algorithms by name). Does nothing if ``hashlib`` is
    already imported.
    """
    if "hashlib" not in sys.modules:
        sys.modules.setdefault("_hashlib", None)  # type: ignore[arg-type]  # import blocked


def lighten_node_imports() -> None:
    """What a node process does before importing its node (see the module's description)."""
    defer_message_code_generator()
    urdf_outline.parse_apart()
    use_builtin_hashes()


def _run(module: str) -> None:
    prepare_node_process()
    lighten_node_imports()
    importlib.import_module(f"audio2pose_ros.ros.nodes.{module}").main()


def audio_features_node() -> None:
    """Console script ``audio_features_node``."""
    _run("audio_features_node")


def inference_node() -> None:
    """Console script ``inference_node``."""
    _run("inference_node")


def motion_filter_node() -> None:
    """Console script ``motion_filter_node``."""
    _run("motion_filter_node")


def pepper_sim_node() -> None:
    """Console script ``pepper_sim_node``."""
    _run("pepper_sim_node")


def console_node() -> None:
    """Console script ``console_node``."""
    _run("console_node")


def voice_out_node() -> None:
    """Console script ``voice_out_node``."""
    _run("voice_out_node")

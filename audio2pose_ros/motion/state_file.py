"""The motion filter's memory across restarts: last commanded pose, stop and enable.

A restarted ``motion_filter_node`` must not move the robot before it knows where the robot is,
and a stop must outlive the process that sent it, as must ``enable: false`` (a restart must not
bring back the motion an operator switched off). Without the robot's measured
joint states the node starts from the pose it last commanded, read from a small JSON file that
it rewrites atomically (a temporary file in the same directory, flushed, then renamed over the
old one) a few times per second and at every stop or release. A file that cannot be used is
reported and ignored; it never stops the node from starting.

The default location is ``$ROS_HOME/audio2pose_ros/domain_<ROS_DOMAIN_ID>/``
(``~/.ros/...`` without ROS_HOME), one file per node by its fully qualified name (namespace
included): two robots, in two namespaces or two domains, never share a file. A file is also
never shared by two live nodes: :class:`StateLock` holds an exclusive lock on
``<file>.lock`` for the node's life (the kernel releases it when the process dies, even by
SIGKILL), and a second node that finds it held refuses to start, naming the file and the
owner's pid.

The times a stop and a disable came into force (``stopped_at_s``, ``disabled_at_s``, wall clock)
are kept too: a release must be published after them to count
(:mod:`~audio2pose_ros.motion.holds`).
:class:`StateStore` is the node's use of its file: the lock, what it held at start, and writes
only of what changed, at a bounded rate. :class:`StateWriter` writes it from a thread of its
own, so the filter's tick never waits on the disk (an fsync takes milliseconds), while a stop or
a disable is written before the node acknowledges it (:meth:`StateWriter.write_now`).
"""

from __future__ import annotations

import fcntl
import json
import math
import os
import socket
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from audio2pose_ros.errors import InputError
from audio2pose_ros.motion.problems import Problem
from audio2pose_ros.robot.description import RobotDescription

FORMAT_VERSION = 1
MAX_FILE_BYTES = 65536  # a state file is a few hundred bytes; anything larger is not ours
RANGE_SLACK_RAD = 1e-6  # rounding allowance of the range check of a saved pose
MIN_SAVE_SPACING_S = 0.1  # a change kept at once is written at most this often (flash wear)
SAVED_POSE_RESOLUTION_RAD = 1e-4  # a pose that moved less than this is not written again


@dataclass(frozen=True)
class FilterMemory:
    """What a restarted filter needs to know.

    Attributes:
        joint_names: the joints of ``position_rad``, in the robot description's order.
        position_rad: the last commanded pose.
        stopped: a stop was in force.
        saved_at_s: wall-clock time of saving (s since the epoch).
        enabled: generated motion was enabled (files written before this field: True).
        stopped_at_s: wall-clock time the stop came into force (None: not kept; older files).
        disabled_at_s: wall-clock time the disable came into force (likewise).
        measured: the robot reported its measured joint states to the process that saved.
    """

    joint_names: tuple[str, ...]
    position_rad: tuple[float, ...]
    stopped: bool
    saved_at_s: float
    enabled: bool = True
    stopped_at_s: float | None = None
    disabled_at_s: float | None = None
    measured: bool = False

    def pose_in_range(self, robot: RobotDescription) -> bool:
        """Whether every saved angle lies inside its joint's range (a pose outside is refused)."""
        return all(
            low - RANGE_SLACK_RAD <= v <= high + RANGE_SLACK_RAD
            for v, low, high in zip(
                self.position_rad, robot.lower_rad, robot.upper_rad, strict=True
            )
        )


def default_state_path(node_name: str, domain_id: str | None = None) -> Path:
    """``$ROS_HOME/audio2pose_ros/domain_<id>/<node>.json`` (ROS_HOME defaults to ``~/.ros``).

    ``node_name`` is the fully qualified name (its namespace becomes part of the file name);
    ``domain_id`` defaults to ``$ROS_DOMAIN_ID`` (0 when unset, as in ROS 2).
    """
    ros_home = os.environ.get("ROS_HOME") or str(Path.home() / ".ros")
    domain = domain_id if domain_id is not None else os.environ.get("ROS_DOMAIN_ID", "").strip()
    domain = "".join(c for c in domain if c.isalnum() or c in "-_") or "0"
    safe = node_name.strip("/").replace("/", "__") or "motion_filter_node"
    return Path(ros_home) / "audio2pose_ros" / f"domain_{domain}" / f"{safe}.json"


class StateFileInUseError(InputError):
    """Another live process holds the state file (two nodes must not share one robot's state)."""


class StateLock:
    """An exclusive, non-blocking lock on ``<state file>.lock``, held until :meth:`release`.

    The lock file names its owner (pid and host) for the message a second node gets.
    """

    def __init__(self, path: Path) -> None:
        """Take the lock of the state file ``path``.

        Raises:
            StateFileInUseError: another process holds it (the message names file and owner).
            OSError: the lock file cannot be created (the directory is not writable).
        """
        self.path = path.with_name(path.name + ".lock")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fd: int | None = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            owner = os.pread(self._fd, 200, 0).decode("utf-8", "replace").strip() or "unknown"
            os.close(self._fd)
            self._fd = None
            raise StateFileInUseError(
                f"state file {path} is in use by another live node ({owner}); give each robot "
                "its own namespace, ROS_DOMAIN_ID or state_file"
            ) from None
        os.ftruncate(self._fd, 0)
        os.pwrite(self._fd, f"pid {os.getpid()} on {socket.gethostname()}".encode(), 0)

    def release(self) -> None:
        """Give the lock up (the kernel also does when the process ends)."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


def save_memory(path: Path, memory: FilterMemory) -> None:
    """Write ``memory`` to ``path`` atomically (readers see the old or the new file, whole).

    Raises:
        OSError: the directory cannot be created or written.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps(
        {
            "format": FORMAT_VERSION,
            "joint_names": list(memory.joint_names),
            "position_rad": list(memory.position_rad),
            "stopped": memory.stopped,
            "enabled": memory.enabled,
            "saved_at_s": memory.saved_at_s,
            "stopped_at_s": memory.stopped_at_s,
            "disabled_at_s": memory.disabled_at_s,
            "measured": memory.measured,
        }
    )
    # a new file of a random name beside the state file, as tempfile.mkstemp makes one (which
    # would cost the filter's process tempfile's imports, 0.6 MB, for this one call)
    temporary = path.with_name(f"{path.name}{os.urandom(6).hex()}.tmp")
    handle = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o600)
    try:
        with os.fdopen(handle, "w", encoding="utf-8") as stream:
            stream.write(text)
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


def load_memory(path: Path, robot: RobotDescription) -> FilterMemory | None:
    """The memory saved at ``path`` for ``robot``, or None when there is no file.

    Raises:
        InputError: the file cannot be read, is not a state file of this version, names other
            joints than ``robot`` or holds non-finite angles (the message names the file).
    """
    try:
        with path.open("rb") as stream:
            raw = stream.read(MAX_FILE_BYTES + 1)
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise InputError(f"{path}: cannot read the filter state: {exc}") from None
    if len(raw) > MAX_FILE_BYTES:
        raise InputError(f"{path}: larger than {MAX_FILE_BYTES} bytes, not a filter state file")
    try:
        data = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise InputError(f"{path}: not a JSON filter state: {exc}") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT_VERSION:
        raise InputError(f"{path}: not a filter state file of format {FORMAT_VERSION}")
    names, positions = data.get("joint_names"), data.get("position_rad")
    stopped, saved_at = data.get("stopped"), data.get("saved_at_s")
    if names != list(robot.names):
        raise InputError(f"{path}: joints {names} are not those of {robot.name}")
    if (
        not isinstance(positions, list)
        or len(positions) != robot.n_joints
        or not all(
            isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
            for v in positions
        )
    ):
        raise InputError(f"{path}: position_rad must be {robot.n_joints} finite angles")
    enabled = data.get("enabled", True)
    if (
        not isinstance(stopped, bool)
        or not isinstance(enabled, bool)
        or not isinstance(saved_at, int | float)
    ):
        raise InputError(
            f"{path}: 'stopped' and 'enabled' must be true/false and 'saved_at_s' a number"
        )
    measured = data.get("measured", False)
    if not isinstance(measured, bool):
        raise InputError(f"{path}: 'measured' must be true/false")
    since = [data.get(key) for key in ("stopped_at_s", "disabled_at_s")]
    if not all(
        v is None or (isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v))
        for v in since
    ):
        raise InputError(f"{path}: 'stopped_at_s' and 'disabled_at_s' must be numbers")
    return FilterMemory(
        tuple(names),
        tuple(float(v) for v in positions),
        stopped,
        float(saved_at),
        enabled,
        None if since[0] is None else float(since[0]),
        None if since[1] is None else float(since[1]),
        measured,
    )


class StateStore:
    """One node's state file: its lock, what it held at start, and when it is written again.

    A write happens only when something kept changed (the pose by at least
    :data:`SAVED_POSE_RESOLUTION_RAD`, so a pose at rest is written once), and a change to be
    kept at once (a stop, a disable) is written at most every :data:`MIN_SAVE_SPACING_S` (a
    flood of them wears no flash): :meth:`save_soon` says when the next write may be now.

    Attributes:
        path: the state file.
        lock: its lock (None when it could not be taken: ``lock_problem`` says why).
        memory: what the file held at start (None: no file, or ``read_problem`` says why not).
        due: a change waits for its write.
    """

    def __init__(self, path: Path, robot: RobotDescription) -> None:
        """Lock the state file ``path`` and read what it holds for ``robot``.

        Raises:
            StateFileInUseError: another live node holds the file.
        """
        self.path = path
        self.robot = robot
        self.lock: StateLock | None = None
        self.lock_problem = ""
        try:
            self.lock = StateLock(path)
        except StateFileInUseError:
            raise
        except OSError as exc:
            self.lock_problem = f"cannot lock it: {exc}"
        self.memory: FilterMemory | None = None
        self.read_problem = ""
        try:
            self.memory = load_memory(path, robot)
        except InputError as exc:
            self.read_problem = str(exc)
        self.due = False
        self.last_write_s = -math.inf  # monotonic time of the last write (or attempt)
        self._written: tuple[object, ...] | None = None

    @property
    def pose_refused(self) -> bool:
        """The file holds a pose outside the joint ranges (refused; its stop and enable kept)."""
        return self.memory is not None and not self.memory.pose_in_range(self.robot)

    def problems(self) -> list[Problem]:
        """What is wrong with the file at start: unlocked (ERROR), unreadable, pose refused."""
        found = [self.unsaved(self.lock_problem, False)] if self.lock_problem else []
        if self.read_problem:
            found.append(Problem("state_file", False, f"state file ignored: {self.read_problem}"))
        if self.pose_refused:
            text = (
                f"the pose saved in {self.path} lies outside the joint ranges: refused (its stop "
                "and enable are kept)"
            )
            found.append(Problem("saved_pose_refused", False, text, 10.0))
        return found

    def unsaved(self, reason: str, stopped: bool) -> Problem:
        """The state cannot be saved: an ERROR until a save succeeds (a stop stays in memory)."""
        held = " The STOP in force" if stopped else " A stop"
        text = (
            f"state file {self.path}: {reason}.{held} stays in force in this process but will "
            "NOT survive a restart"
        )
        return Problem("state_file_unsaved", True, text, math.inf)

    def saved_pose(self) -> np.ndarray | None:
        """The saved pose, when there is one inside the joint ranges."""
        if self.memory is None or self.pose_refused:
            return None
        return np.array(self.memory.position_rad)

    def save(self, memory: FilterMemory, now_s: float) -> bool:
        """Write ``memory`` atomically unless it is what was last written; True when written.

        Args:
            memory: what to keep.
            now_s: monotonic time now.

        Raises:
            OSError: the file cannot be written (it is tried again at the next save).
        """
        resolution = SAVED_POSE_RESOLUTION_RAD
        key = (
            tuple(round(v / resolution) for v in memory.position_rad),
            memory.stopped,
            memory.enabled,
            memory.stopped_at_s,
            memory.disabled_at_s,
            memory.measured,
        )
        self.due = False
        if key == self._written:
            return False
        self.last_write_s = now_s
        save_memory(self.path, memory)
        self._written = key
        return True

    def save_soon(self, now_s: float) -> bool:
        """A change is to be kept at once: True when it may be written now (else it is due)."""
        self.due = True
        return self.spaced(now_s)

    def spaced(self, now_s: float) -> bool:
        """Whether a write at ``now_s`` keeps :data:`MIN_SAVE_SPACING_S` from the last one."""
        return now_s - self.last_write_s >= MIN_SAVE_SPACING_S


class StateWriter:
    """Writes a :class:`StateStore` off the caller's thread; never an older memory over a newer.

    :meth:`submit` (the tick) hands a memory to the writer thread and returns at once: the
    thread writes the newest memory submitted, those submitted meanwhile are replaced unwritten.
    :meth:`write_now` (a stop, a disable) writes in the caller's thread and returns when the
    file holds it. Every memory has its place in the order of submission: one submitted earlier
    is never written after a later one (the thread skips it), so a pose handed over before a
    stop never overwrites the stop. The thread's last outcome is read by the tick
    (:meth:`take_outcome`): whether it wrote, or the error that kept it from writing.
    """

    def __init__(self, store: StateStore) -> None:
        """The writer of ``store``; its thread starts at the first :meth:`submit`."""
        self.store = store
        self._ordered = threading.Lock()  # one write at a time, in the order of submission
        self._wake = threading.Condition()
        self._submitted = 0  # the place of the newest memory handed over
        self._written = 0  # the place of the newest memory written (or tried)
        self._pending: tuple[int, FilterMemory, float] | None = None
        self._outcome: tuple[bool, OSError | None] | None = None
        self._closed = False
        self._thread: threading.Thread | None = None
        self.writes_off_thread = 0

    def submit(self, memory: FilterMemory, now_s: float) -> None:
        """Have ``memory`` written by the writer thread (replacing one not written yet)."""
        with self._wake:
            self._submitted += 1
            self._pending = (self._submitted, memory, now_s)
            if self._thread is None:
                self._thread = threading.Thread(
                    target=self._run, name="state file writer", daemon=True
                )
                self._thread.start()
            self._wake.notify()

    def write_now(self, memory: FilterMemory, now_s: float) -> bool:
        """Write ``memory`` now, in this thread (replacing one not written yet); True: written.

        Raises:
            OSError: the file cannot be written.
        """
        with self._wake:
            self._submitted += 1
            place = self._submitted
            self._pending = None
        return self._write(place, memory, now_s)

    def take_outcome(self) -> tuple[bool, OSError | None] | None:
        """The writer thread's outcome since the last call: (written, error); None: none."""
        outcome, self._outcome = self._outcome, None
        return outcome

    def close(self) -> None:
        """Write what is still pending, then end the thread (the node is destroyed)."""
        with self._wake:
            self._closed = True
            self._wake.notify()
        if self._thread is not None:
            self._thread.join()

    def _write(self, place: int, memory: FilterMemory, now_s: float) -> bool:
        with self._ordered:
            if place < self._written:  # a newer memory is in the file already
                return False
            self._written = place
            return self.store.save(memory, now_s)

    def _run(self) -> None:
        while True:
            with self._wake:
                while self._pending is None and not self._closed:
                    self._wake.wait()
                if self._pending is None:
                    return
                place, memory, now_s = self._pending
                self._pending = None
            try:
                written = self._write(place, memory, now_s)
            except OSError as exc:
                self._outcome = (False, exc)
            else:
                self.writes_off_thread += written
                self._outcome = (written, None)

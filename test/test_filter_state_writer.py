"""The state file is written off the filter's tick, and a stop is written before it is acknowledged.

The verdicts are the order of events (a tick's start and end, each write with the thread that
made it, the node's STOP log line), never times: an fsync takes milliseconds, which the 50 Hz
tick must not wait for, while a stop must be on disk before the node says it is in force.
"""

from __future__ import annotations

import threading
import time

import pytest
from std_msgs.msg import Bool

from audio2pose_ros.motion import state_file
from audio2pose_ros.motion.state_file import FilterMemory, StateStore, StateWriter, load_memory
from audio2pose_ros.ros.nodes.motion_filter_node import MotionFilterNode
from audio2pose_ros.ros.player import rclpy_session

WAIT_S = 30  # bounds a hung thread only: no verdict on time


class Events:
    """What happened, in order: (what, thread id, detail)."""

    def __init__(self) -> None:
        self.log: list[tuple[str, int, object]] = []
        self.lock = threading.Lock()

    def add(self, what: str, detail: object = None) -> None:
        with self.lock:
            self.log.append((what, threading.get_ident(), detail))

    def wait_for(self, what: str, count: int = 1) -> None:
        deadline = time.monotonic() + WAIT_S
        while sum(e[0] == what for e in self.log) < count:
            assert time.monotonic() < deadline, f"no {what}: {self.log}"
            time.sleep(0.005)


@pytest.fixture
def events(monkeypatch) -> Events:
    """Every state file write is an event (with the thread that made it)."""
    found = Events()
    real_save = state_file.save_memory

    def save(path, memory):
        found.add("write", memory.stopped)
        real_save(path, memory)

    monkeypatch.setattr(state_file, "save_memory", save)
    return found


class Logger:
    """The node's logger, its lines recorded as events too."""

    def __init__(self, real, found: Events) -> None:
        self.real, self.found = real, found

    def warning(self, message: str, **kwargs) -> None:
        self.found.add("log", message)
        self.real.warning(message, **kwargs)

    def __getattr__(self, name: str):
        return getattr(self.real, name)


@pytest.fixture
def filter_node(tmp_path, monkeypatch, events):
    monkeypatch.setenv("ROS_HOME", str(tmp_path))
    args = [
        "--ros-args",
        "-p",
        f"state_file:={tmp_path / 'state.json'}",
        "-p",
        "state_save_period_s:=0.05",
        "-p",
        "start_without_measured_pose:=true",  # no robot here: the filter starts and ticks
    ]
    with rclpy_session(args):
        node = MotionFilterNode(subscribe_graph=False)
        logger = Logger(node.get_logger(), events)
        monkeypatch.setattr(node, "get_logger", lambda: logger)
        on_tick = node.on_tick

        def tick() -> None:
            events.add("tick start")
            on_tick()
            events.add("tick end")

        node.on_tick = tick
        yield node
        node.destroy_node()


def test_when_the_filter_ticks_expect_its_state_written_by_another_thread(filter_node, events):
    node = filter_node
    node.on_startup_timeout()  # started (from neutral): the start's pose is saved
    for step in range(40):  # the pose moves, and the save period passes between ticks
        node.on_poses((node.robot.neutral_rad + 0.002 * step)[None, :], node.now_s())
        node.on_tick()
        time.sleep(0.01)
    events.wait_for("write", 2)
    tick_thread = threading.get_ident()
    inside = False
    for what, thread, _ in list(events.log):
        inside = {"tick start": True, "tick end": False}.get(what, inside)
        if what == "write":
            assert not (inside and thread == tick_thread), events.log
            assert thread != tick_thread  # every periodic write was the writer thread's
    assert node.state_writer.writes_off_thread >= 2


def test_when_a_stop_comes_expect_it_written_before_the_node_acknowledges_it(filter_node, events):
    node = filter_node
    node.on_startup_timeout()
    time.sleep(0.2)  # the start's write is done and spaced from the stop's
    node.state_writer.take_outcome()
    before = len(events.log)
    node.on_stop(Bool(data=True), None)
    after = events.log[before:]
    order = [what for what, _, _ in after if what in ("write", "log")]
    assert order[:2] == ["write", "log"], after  # on disk, then "STOP"
    assert after[0][1] == threading.get_ident()  # written by the stop's own callback
    assert after[0][2] is True
    memory = load_memory(node.state_path, node.robot)
    assert memory is not None
    assert memory.stopped


def memory(robot, stopped: bool, offset: float) -> FilterMemory:
    pose = tuple(float(v) + offset for v in robot.neutral_rad)
    return FilterMemory(tuple(robot.names), pose, stopped, time.time())


def test_when_a_stop_is_written_while_an_older_pose_waits_expect_the_stop_kept(
    tmp_path, robot, monkeypatch
):
    """A pose handed over before a stop never overwrites the stop, whatever the thread does."""
    store = StateStore(tmp_path / "state.json", robot)
    writer = StateWriter(store)
    release = threading.Event()
    entered = threading.Event()
    real_save = store.save

    def slow_save(memory_, now_s):  # the writer thread's first write waits on a slow disk
        if threading.current_thread() is not threading.main_thread() and not release.is_set():
            entered.set()
            release.wait(WAIT_S)
        return real_save(memory_, now_s)

    monkeypatch.setattr(store, "save", slow_save)
    writer.submit(memory(robot, False, 0.01), time.monotonic())  # the thread takes it, waits
    assert entered.wait(WAIT_S)
    writer.submit(memory(robot, False, 0.02), time.monotonic())  # waits behind it
    stop_written = threading.Thread(
        target=writer.write_now, args=(memory(robot, True, 0.03), time.monotonic())
    )
    stop_written.start()  # waits for the thread's write in progress
    release.set()
    stop_written.join(WAIT_S)
    writer.close()
    kept = load_memory(store.path, robot)
    assert kept is not None
    assert kept.stopped
    assert kept.position_rad[0] == pytest.approx(robot.neutral_rad[0] + 0.03)

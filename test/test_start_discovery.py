"""Not knowing where the robot is never moves it: slow discovery, and a second publisher.

motion_filter_node in this process (:mod:`clocked_filter`): the graph shows the robot's driver
late (a robot over Wi-Fi: later than ``startup_timeout_s``), or a second publisher's first
message arrives before the graph shows that publisher. The verdicts are what the filter
started from, in which order things happened, and where its first command is.
"""

from __future__ import annotations

import numpy as np
import pytest
from clocked_filter import clocked_nodes, measured, moved_arm
from diagnostic_msgs.msg import DiagnosticStatus

from audio2pose_ros.motion.measured import SOURCE_WINDOW_S

pytestmark = pytest.mark.ros


@pytest.fixture
def clocked(tmp_path, monkeypatch, robot):
    """motion_filter_node on a controlled clock and graph (:func:`clocked_nodes`)."""
    yield from clocked_nodes(tmp_path, monkeypatch, robot)


def first_command(node, now_s: float) -> np.ndarray:
    """The filter's first command after its start (as the tick computes it)."""
    command, _ = node.filter.tick(now_s)
    return command


def test_when_discovery_takes_longer_than_the_startup_timeout_expect_nothing_commanded_till_then(
    clocked, robot
):
    """No state file, the robot's driver discovered 6 s after start (a robot over Wi-Fi).

    Before: the start took "no publisher yet" for "nothing publishes" at startup_timeout_s and
    commanded the robot toward neutral, 0.6 rad from where it stood.
    """
    node, clock, graph, _ = clocked(saved=False)
    events = []
    for now_s in np.arange(1.0, 6.0, 0.1):  # startup_timeout_s passed, then the 0.1 s checks
        clock.now = float(now_s)
        node.on_startup_timeout()
        events.append(node.started_from or "waiting")
    assert set(events) == {"waiting"}, "started without knowing where the robot is"
    level, said, _ = node.current_problems()["start_pose"]
    assert level == DiagnosticStatus.WARN
    assert "no measured pose on joint_states (no publisher)" in said
    assert "commanding nothing" in said
    assert node.diagnostic_values()["started_from"] == "waiting"
    clock.now, graph.publishers = 6.0, [1]  # discovered at last
    node.on_startup_timeout()
    assert not node.started
    clock.now = 6.05
    node.on_measured(*measured(robot, moved_arm(robot)))
    assert node.started_from == "measured pose"
    assert np.abs(first_command(node, 6.06) - moved_arm(robot)).max() < 0.02


def test_when_a_second_publishers_first_message_comes_before_its_discovery_expect_a_hold(
    clocked, robot
):
    """The graph shows the robot's driver; a second robot's pose arrives before the graph
    shows its publisher, then the robot's own. Before: the first message started the filter
    from the second robot's pose (1 publisher on the graph), the conflict reported afterwards.
    """
    node, clock, graph, _ = clocked(saved=False)
    real = moved_arm(robot)
    wrong = real.copy()
    wrong[robot.names.index("LShoulderPitch")] += 1.37
    clock.now, graph.publishers = 0.5, [1]  # the robot's driver, discovered, not heard yet
    node.on_measured(*measured(robot, wrong, gid=2))  # its first message, before discovery
    assert not node.started, "started from a pose whose publisher the graph does not show yet"
    levels = []
    for k in range(40):  # both send at 50 Hz for 0.8 s
        clock.now = last_wrong_s = 0.52 + 0.02 * k
        node.on_measured(*measured(robot, real, gid=1))
        node.on_measured(*measured(robot, wrong, gid=2))
        levels.append(node.current_problems().get("measured_sources", (None, ""))[0])
        assert not node.started, "started while two sources of the robot's pose disagree"
    assert levels[-1] == DiagnosticStatus.ERROR
    assert "disagree by 1.37 rad" in node.current_problems()["measured_sources"][1]
    clock.now, graph.publishers = 1.5, [1, 2]  # the graph shows the second one at last
    node.on_startup_timeout()
    assert node.current_problems()["start_pose"][0] == DiagnosticStatus.ERROR  # held
    now_s = 1.5
    while not node.started and now_s < 10.0:  # the second robot's driver stopped
        now_s += 0.02
        clock.now = now_s
        node.on_measured(*measured(robot, real, gid=1))
    assert node.started_from == "measured pose"
    assert now_s > last_wrong_s + SOURCE_WINDOW_S  # only once the second one was quiet
    assert np.abs(first_command(node, now_s + 0.01) - real).max() < 0.02

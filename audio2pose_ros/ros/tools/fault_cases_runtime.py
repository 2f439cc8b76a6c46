"""Fault cases of the runtime: tracks, start poses, state files, stops, liveness, names, floods.

Part of ``audio2pose faults`` (:func:`~audio2pose_ros.ros.tools.fault_campaign.cases` appends
:func:`runtime_cases`). Each case attacks the live graph over DDS as in the rest of the
campaign and reads the outcome from what the robot receives, the nodes' /diagnostics, the
supervisor and the state file:

- a bag replay of a recording that holds the robot's commands;
- a burst of consistent wrong poses, a second ``raw_trajectory`` publisher;
- raw poses that sweep a hand into the hip (the self-collision guard);
- a restart while the robot reports a pose with a NaN and an out-of-range joint, after the arm
  was moved while the filter was down;
- a second filter with the same state file, a filter in another namespace;
- older panels' latched ``stop: false`` (and a newer latched ``stop: true``) across a restart;
- a stop that cannot be saved;
- a SIGSTOPped filter impersonated on /diagnostics (:func:`impersonated_sigstop_case`, which
  extends :func:`sigstop_case` and takes the place of the plain SIGSTOP case);
- floods on stop, head_offset, joint_states, raw_trajectory and parameter sets;
- SIGKILL of inference_node, twice: the time to its next raw pose.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import time
from collections.abc import Callable

import numpy as np
from audio_common_msgs.msg import AudioData, AudioInfo
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from std_msgs.msg import Bool
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros import topics
from audio2pose_ros.motion.body_guard import TOLERANCE_M as BODY_TOLERANCE_M
from audio2pose_ros.motion.filter_settings import MotionFilterSettings
from audio2pose_ros.robot.body import BodyModel
from audio2pose_ros.ros.diagnosed_node import status_name
from audio2pose_ros.ros.qos import LATCHED_QOS, STREAM_QOS
from audio2pose_ros.ros.supervisor import executable_command
from audio2pose_ros.ros.tools.fault_harness import (
    MAX_DEVIATION_RAD,
    STREAM_PERIOD_S,
    Campaign,
    Case,
    Commands,
    Outcome,
)
from audio2pose_ros.timebase import SAMPLE_RATE_HZ

FILTER = "motion_filter_node"
ERROR_LEVEL = 2
FLOOD_S = 1.5
MIN_COMMAND_RATE_HZ = 45.0  # joint_angles runs at 50 Hz
MAX_FLOOD_GAP_S = 0.1
MAX_STATE_WRITES = 3  # while a flood does not change the state
RESPAWN_SEARCH_S = 30.0  # how long a kill's case waits for raw poses again: only a hung node misses
# the left hand 7 cm inside the hip, within every joint limit (raw poses of a wrong model)
BODY_ATTACK_POSE = {
    "LShoulderPitch": 1.3,
    "LShoulderRoll": 0.13,
    "LElbowRoll": -1.24,
    "LElbowYaw": 0.28,
}


def _commands_since(c: Campaign, start: int) -> Commands:
    window = c.probe.commands[start:]
    return Commands(
        np.array([t for t, _ in window]),
        np.array([p for _, p in window]).reshape(-1, c.robot.n_joints),
    )


def _while(c: Campaign, seconds: float, action: Callable[[], None], period_s: float) -> Commands:
    """Run ``action`` every ``period_s`` for ``seconds`` (benign stream on); the commands."""
    start, end = len(c.probe.commands), time.monotonic() + seconds
    while time.monotonic() < end:
        action()
        c.probe.spin_for(period_s)
    return _commands_since(c, start)


def _reversals_per_s(window: Commands, joint: int) -> float:
    steps = np.diff(window.positions_rad[:, joint])
    signs = np.sign(steps[np.abs(steps) > 1e-4])
    duration = float(window.times_s[-1] - window.times_s[0]) if len(window.times_s) > 1 else 1.0
    return float(np.sum(signs[1:] != signs[:-1])) / max(duration, 1e-3)


def _filter_error(c: Campaign, text: str) -> bool:
    level, message, _ = c.probe.diagnostics.get(FILTER, (0, "", {}))
    return level >= ERROR_LEVEL and text in message


# --- wrong tracks -----------------------------------------------------------------------------


def _burst(c: Campaign) -> Outcome:
    pose = c.pose_a
    joint = c.robot.names.index("LShoulderPitch")
    wrong = pose.copy()
    wrong[joint] = float(np.clip(pose[joint] + 1.2, c.robot.lower_rad[joint], 2.0))
    c.probe.raw.publish(c.probe.trajectory(np.repeat(wrong[None, :], 30, axis=0)))
    window = c.probe.observe(2.0)
    worst = window.worst_deviation(pose)
    return Outcome(f"arm moved {worst:.3f} rad", worst <= MAX_DEVIATION_RAD, worst)


def _second_publisher(c: Campaign) -> Outcome:
    other = c.probe.create_publisher(JointTrajectory, topics.RAW_TRAJECTORY, STREAM_QOS)
    other_pose = c.pose_a.copy()  # close enough to pass the gate: both tracks are plausible
    other_pose[c.robot.names.index("LShoulderPitch")] += 0.15
    try:
        window = _while(
            c,
            2.0,
            lambda: other.publish(c.probe.trajectory(np.stack([other_pose, other_pose]))),
            0.02,
        )
        reported = _filter_error(c, "second publisher")
    finally:
        c.probe.destroy_publisher(other)
    worst = window.worst_deviation(c.pose_a)
    reversals = _reversals_per_s(window, c.robot.names.index("LShoulderPitch"))
    ok = worst <= 0.02 and reported
    did = f"moved {worst:.3f} rad, {reversals:.1f} reversals/s; ERROR on /diagnostics: {reported}"
    return Outcome(did, ok, worst)


def _into_the_body(c: Campaign) -> Outcome:
    """Raw poses sweep the left hand into the hip and back: no command inside the margin."""
    body = BodyModel.load(c.robot)
    inside = c.pose_a.copy()
    for name, value in BODY_ATTACK_POSE.items():
        inside[c.robot.names.index(name)] = value
    start, steps = c.pose_a.copy(), 50  # 1 s in, 1 s held, 1 s back out
    path = [start + (inside - start) * k / steps for k in range(steps + 1)]
    path += [inside] * steps + path[::-1]
    first = len(c.probe.commands)
    try:
        for pose in path:
            c.probe.pose = pose
            c.probe.spin_for(STREAM_PERIOD_S)
        warned = "self-collision guard" in c.probe.diagnostics.get(FILTER, (0, "", {}))[1]
        window = _commands_since(c, first)
    finally:
        c.probe.pose = c.pose_a
    margin = MotionFilterSettings().body_margin_m  # the graph runs the default parameters
    clearance = body.clearance(window.positions_rad) if len(window.times_s) else np.zeros(0)
    closest = float(clearance.min()) if len(clearance) else math.nan
    raw = float(body.clearance(inside))
    ok = len(clearance) > 0 and closest >= margin - BODY_TOLERANCE_M
    did = (
        f"raw poses {raw * 100:.1f} cm from the body; closest command {closest * 100:.2f} cm"
        f" (margin {margin * 100:.0f} cm); WARN naming links: {warned}"
    )
    return Outcome(did, ok, math.nan)


# --- start pose -------------------------------------------------------------------------------


def _restart_partial_measurement(c: Campaign) -> Outcome:
    """Restart after the arm was moved; the robot reports one NaN and one out-of-range joint."""
    names = c.robot.names
    moved = c.pose_a.copy()
    moved[names.index("LShoulderPitch")] += 0.6
    head, hip = names.index("HeadPitch"), names.index("HipRoll")
    reading = moved.copy()
    reading[head] = c.robot.lower_rad[head] - 0.05
    reading[hip] = math.nan
    expected = moved.copy()
    expected[head] = c.robot.lower_rad[head]
    old = c.pid(FILTER)
    c.probe.robot_reports = False
    killed_s = c.probe.get_clock().now().nanoseconds * 1e-9
    os.kill(old, signal.SIGKILL)
    c.probe.pose = moved  # the stream resumes where the robot now is
    deadline = time.monotonic() + 30.0
    try:
        while time.monotonic() < deadline and c.pid(FILTER) == old:
            c.probe.measured.publish(c.probe.joint_state_msg(reading))
            c.probe.spin_for(0.02)
        start = len(c.probe.commands)
        while time.monotonic() < deadline and len(c.probe.commands) - start < 10:
            c.probe.measured.publish(c.probe.joint_state_msg(reading))
            c.probe.spin_for(0.02)
    finally:
        c.probe.robot_reports = True
    window = _commands_since(c, start)
    new = window.times_s > killed_s  # not the old process's last commands, still in flight
    first = Commands(window.times_s[new], window.positions_rad[new])
    if not len(first.times_s):
        return Outcome("no commands after the restart", False)
    mask = np.arange(c.robot.n_joints) != hip
    worst = first.worst_deviation(expected, mask)
    hip_off = abs(float(first.positions_rad[0, hip] - c.pose_a[hip]))
    ok = worst <= MAX_DEVIATION_RAD and hip_off <= MAX_DEVIATION_RAD
    c.probe.robot_pose = moved
    return Outcome(f"first command {worst:.3f} rad from the measured pose", ok, worst)


# --- state files and names ----------------------------------------------------------------------


def _filter_process(c: Campaign, *ros_args: str) -> list[str]:
    return [*executable_command(FILTER), "--ros-args", *ros_args]


def _shared_state_file(c: Campaign) -> Outcome:
    command = _filter_process(c, "-r", "__ns:=/intruder", "-p", f"state_file:={c.state_file}")
    result = subprocess.run(command, capture_output=True, text=True, timeout=60, check=False)
    named = str(c.state_file) in result.stderr
    ok = result.returncode == 78 and named
    return Outcome(f"second filter exit status {result.returncode}; names the file: {named}", ok)


def _namespaced_status(c: Campaign) -> Outcome:
    state = c.state_file.parent.parent / "pepper2_state.json"
    process = subprocess.Popen(
        _filter_process(c, "-r", "__ns:=/pepper2", "-p", f"state_file:={state}"),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 30.0
        while (
            time.monotonic() < deadline and "pepper2/motion_filter_node" not in c.probe.diagnostics
        ):
            c.probe.spin_for(0.1)
        c.probe.diagnostics.pop(FILTER, None)
        c.probe.spin_for(1.0)
        both = {"pepper2/motion_filter_node", FILTER} <= set(c.probe.diagnostics)
    finally:
        process.terminate()
        process.wait(timeout=10)
        c.probe.diagnostics.pop("pepper2/motion_filter_node", None)
    did = (
        f"statuses {status_name('/pepper2/' + FILTER)!r} and {status_name('/' + FILTER)!r}: {both}"
    )
    return Outcome(did, both)


# --- stops ------------------------------------------------------------------------------------


def _older_panels(c: Campaign) -> Outcome:
    """An older panel latched stop: false, a newer one stop: true; a one-shot stop, a restart."""
    older = c.probe.create_publisher(Bool, topics.STOP, LATCHED_QOS)
    older.publish(Bool(data=False))
    c.probe.spin_for(0.3)
    newer = c.probe.create_publisher(Bool, topics.STOP, LATCHED_QOS)
    c.probe.stop.publish(Bool(data=True))  # the operator's stop
    c.probe.spin_for(0.2)
    newer.publish(Bool(data=True))
    c.probe.spin_for(0.3)
    try:
        old = c.pid(FILTER)
        killed_s = c.probe.get_clock().now().nanoseconds * 1e-9
        os.kill(old, signal.SIGKILL)
        c.probe.destroy_publisher(c.probe.stop)  # the one-shot sender is gone
        c.probe.stop = c.probe.create_publisher(Bool, topics.STOP, LATCHED_QOS)
        c.probe.pose = c.pose_b
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline and c.pid(FILTER) == old:
            c.probe.spin_for(0.05)
        window = c.probe.observe_restart(killed_s, timeout_s=30.0, seconds=4.0)
        worst = window.worst_deviation(c.pose_a)
        held = bool(len(window.times_s)) and worst <= 0.02
        c.probe.destroy_publisher(newer)
        older.publish(Bool(data=False))  # a release published now: it counts
        released = c.probe.settle(c.pose_b, timeout_s=10.0)
    finally:
        c.probe.destroy_publisher(older)
        c.probe.pose = c.pose_a
    did = f"moved {worst:.3f} rad after the restart (still stopped: {held}); released: {released}"
    return Outcome(did, held and released, worst)


def _unsaved_stop(c: Campaign) -> Outcome:
    directory = c.state_file.parent
    away = directory.with_name(directory.name + ".away")
    directory.rename(away)
    directory.write_text("not a directory")  # every save now fails
    try:
        c.probe.stop.publish(Bool(data=True))
        c.probe.pose = c.pose_b
        window = c.probe.observe(2.0)
        reported = _filter_error(c, "will NOT survive a restart")
        worst = window.worst_deviation(c.pose_a)
    finally:
        directory.unlink()
        away.rename(directory)
        c.probe.stop.publish(Bool(data=False))
        c.probe.pose = c.pose_a
    ok = reported and worst <= 0.02
    return Outcome(f"ERROR on /diagnostics: {reported}; moved {worst:.3f} rad", ok, worst)


# --- liveness ---------------------------------------------------------------------------------


def sigstop_case(c: Campaign) -> Outcome:
    """SIGSTOP the filter: it must be reported STALE before it is killed, then replaced.

    On an idle machine STALE shows about 1.2 s after the stop (``STALE_AFTER_S`` after the last
    heartbeat, read every 0.1 s, reported every 0.2 s). The case asks only that it shows before
    the kill: a busy CI machine once delayed this process's report to 3.4 s, and the order is
    what an operator relies on (a warning, then a restart).
    """
    node = "motion_filter_node"
    old, silences = c.pid(node), c.supervisor.silences[node]
    stale_before = c.probe.stale_reports.get(node, 0)
    start = time.monotonic()
    os.kill(old, signal.SIGSTOP)
    deadline = start + 10.0
    killed_s = noticed_s = math.inf
    while time.monotonic() < deadline and killed_s == math.inf:
        c.probe.spin_for(0.02)
        now = time.monotonic() - start
        if noticed_s == math.inf and c.probe.stale_reports.get(node, 0) != stale_before:
            noticed_s = now
        if c.supervisor.silences[node] != silences:
            killed_s = now
    if killed_s == math.inf:
        os.kill(old, signal.SIGCONT)
        return Outcome(f"STALE after {noticed_s:.1f} s, not restarted within 10 s", False)
    while time.monotonic() < deadline + 10.0 and c.pid(node) == old:
        c.probe.spin_for(0.05)
    restarted_s = time.monotonic() - start
    resumed = c.probe.settle(c.pose_a, timeout_s=15.0)
    ok = noticed_s < killed_s and c.pid(node) != old and resumed
    did = (
        f"STALE on /diagnostics after {noticed_s:.1f} s, killed after {killed_s:.1f} s and "
        f"restarted after {restarted_s:.1f} s; tracking again: {resumed}"
    )
    return Outcome(did, ok)


def _impersonated_sigstop(c: Campaign) -> Outcome:
    impostor = c.probe.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)

    def publish() -> None:
        pid = KeyValue(key="pid", value=str(c.pid(FILTER)))
        status = DiagnosticStatus(name=status_name("/" + FILTER), values=[pid])
        impostor.publish(DiagnosticArray(status=[status]))

    timer = c.probe.create_timer(0.1, publish)
    try:
        return sigstop_case(c)
    finally:
        c.probe.destroy_timer(timer)
        c.probe.destroy_publisher(impostor)


# --- floods -----------------------------------------------------------------------------------


def _flood(
    send: Callable[[Campaign], None], check_state: bool = False
) -> Callable[[Campaign], Outcome]:
    def run(c: Campaign) -> Outcome:
        writes, inode = 0, c.state_file.stat().st_ino
        sent, start = 0, len(c.probe.commands)
        end = time.monotonic() + FLOOD_S
        while time.monotonic() < end:
            for _ in range(5):
                send(c)
            sent += 5
            c.probe.spin_for(0.001)
            if check_state and c.state_file.stat().st_ino != inode:
                writes, inode = writes + 1, c.state_file.stat().st_ino
        window = _commands_since(c, start)
        rate = len(window.times_s) / FLOOD_S
        gap, worst = window.longest_gap_s(), window.worst_deviation(c.pose_a)
        ok = rate >= MIN_COMMAND_RATE_HZ and gap <= MAX_FLOOD_GAP_S and worst <= 0.02
        did = (
            f"{sent / FLOOD_S:.0f} msg/s sent; commands {rate:.0f} Hz, longest gap "
            f"{gap * 1e3:.0f} ms, moved {worst:.3f} rad"
        )
        if check_state:
            ok = ok and writes <= MAX_STATE_WRITES
            did += f"; state file written {writes} times"
        return Outcome(did, ok, worst)

    return run


def _send_release(c: Campaign) -> None:
    c.probe.stop.publish(Bool(data=False))


def _send_offset(c: Campaign) -> None:
    c.probe.head_offset.publish(c.probe.joint_state_msg(np.array([0.0]), names=("HeadYaw",)))


def _send_target(c: Campaign) -> None:
    head_yaw = c.pose_a[c.robot.names.index("HeadYaw")]  # where the head is: no motion
    c.probe.head_target.publish(c.probe.joint_state_msg(np.array([head_yaw]), names=("HeadYaw",)))


def _send_enable(c: Campaign) -> None:
    c.probe.enable.publish(Bool(data=True))


def _send_measured(c: Campaign) -> None:
    c.probe.measured.publish(c.probe.joint_state_msg(c.probe.robot_pose))


def _send_raw(c: Campaign) -> None:
    c.probe.raw.publish(c.probe.trajectory(np.stack([c.pose_a, c.pose_a])))


def _parameter_flood(c: Campaign) -> Outcome:
    client = c.probe.set_filter_parameters
    value = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=1.0)
    request = SetParameters.Request(parameters=[Parameter(name="head_gain", value=value)])
    pending: list[object] = []
    answered = 0

    def send(_: Campaign) -> None:
        nonlocal answered
        done = [f for f in pending if f.done()]  # type: ignore[attr-defined]
        answered += len(done)
        pending[:] = [f for f in pending if not f.done()]  # type: ignore[attr-defined]
        if len(pending) < 50:
            pending.append(client.call_async(request))

    outcome = _flood(send)(c)
    outcome.did = f"{answered / FLOOD_S:.0f} parameter sets/s answered; " + outcome.did
    return outcome


# --- respawn ----------------------------------------------------------------------------------


def _replayed_recording(c: Campaign) -> Outcome:
    """`audio2pose bag replay` of a recording whose commands hold the arm 1 rad away."""
    import tempfile
    from pathlib import Path

    from naoqi_bridge_msgs.msg import JointAnglesWithSpeed
    from rclpy.serialization import serialize_message

    from audio2pose_ros.data.bag import BagWriter

    far = c.pose_a.copy()
    far[c.robot.names.index("LShoulderPitch")] -= 1.0
    command = JointAnglesWithSpeed(
        joint_names=list(c.robot.names), joint_angles=[float(v) for v in far], speed=1.0
    )
    data = serialize_message(command)
    with tempfile.TemporaryDirectory(prefix="audio2pose_replay_") as tmp:
        bag = Path(tmp) / "recording"
        with BagWriter(bag) as writer:
            for i in range(100):  # 2 s of recorded commands at 50 Hz
                writer.write(
                    topics.absolute(topics.JOINT_ANGLES),
                    "naoqi_bridge_msgs/msg/JointAnglesWithSpeed",
                    i * 20_000_000,
                    data,
                )
            info = AudioInfo(channels=1, sample_rate=SAMPLE_RATE_HZ, sample_format="S16LE")
            info.coding_format = "wave"
            writer.write(
                topics.absolute(topics.AUDIO_INFO),
                "audio_common_msgs/msg/AudioInfo",
                0,
                serialize_message(info),
            )
        start = len(c.probe.commands)
        replay = subprocess.Popen(
            [*executable_command("audio2pose"), "bag", "replay", str(bag), "--wait-s", "0"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        deadline = time.monotonic() + 30.0
        while replay.poll() is None and time.monotonic() < deadline:
            c.probe.spin_for(0.05)
        if replay.poll() is None:
            replay.kill()
        told = "not replayed: /joint_angles" in (replay.communicate()[1] or "")
    window = _commands_since(c, start)
    worst = window.worst_deviation(c.pose_a) if len(window.times_s) else math.nan
    ok = told and len(window.times_s) > 0 and worst <= MAX_DEVIATION_RAD
    return Outcome(
        f"robot moved {worst:.3f} rad; replay said it left /joint_angles out: {told}", ok, worst
    )


def _respawn(c: Campaign) -> Outcome:
    node = "inference_node"
    arrivals: list[float] = []
    sub = c.probe.create_subscription(
        JointTrajectory, topics.RAW_TRAJECTORY, lambda _: arrivals.append(time.monotonic()), 100
    )
    c.probe.streaming = False  # every raw pose now comes from inference_node
    info = AudioInfo(
        channels=1,
        sample_rate=SAMPLE_RATE_HZ,
        sample_format="S16LE",
        bitrate=0,
        coding_format="wave",
    )
    c.probe.audio_info.publish(info)
    chunk = AudioData(data=bytes(2 * SAMPLE_RATE_HZ // 100))  # 10 ms of silence

    def until_pose(timeout_s: float) -> float:
        start, count = time.monotonic(), len(arrivals)
        while time.monotonic() - start < timeout_s and len(arrivals) == count:
            c.probe.audio.publish(chunk)
            c.probe.spin_for(0.01)
        return arrivals[-1] - start if len(arrivals) > count else math.inf

    times = []
    try:
        if not math.isfinite(until_pose(30.0)):
            return Outcome("inference_node publishes no poses", False)
        for _ in range(2):
            old = c.pid(node)
            os.kill(old, signal.SIGKILL)
            killed = time.monotonic()
            while time.monotonic() - killed < RESPAWN_SEARCH_S and c.pid(node) == old:
                c.probe.spin_for(0.01)
            arrivals.clear()
            until_pose(RESPAWN_SEARCH_S - (time.monotonic() - killed))
            times.append(arrivals[0] - killed if arrivals else math.inf)
    finally:
        c.probe.destroy_subscription(sub)
        c.probe.streaming = True
    # The verdict is that poses come back after each kill; how soon (the restarted node's start-up,
    # longer on a loaded machine) is a figure, and the supervisor's timing is test_supervisor's.
    ok = all(math.isfinite(t) for t in times)
    return Outcome(
        f"next raw pose {times[0]:.1f} s after SIGKILL; {times[1]:.1f} s after a second", ok
    )


def impersonated_sigstop_case() -> Case:
    """SIGSTOP of the filter while another process publishes its status name and pid."""
    return Case(
        "SIGSTOP motion_filter_node, an impostor publishes its status",
        "reported STALE before it is killed, restarted after 5 s of silence",
        _impersonated_sigstop,
    )


def runtime_cases() -> list[Case]:
    """The cases of this module, in the order they run."""
    flood = f"commands >= {MIN_COMMAND_RATE_HZ:g} Hz, no gap > {MAX_FLOOD_GAP_S * 1e3:.0f} ms"
    return [
        Case(
            "bag replay of a recording with commands 1 rad away",
            "replays the audio only; the robot stays on its track",
            _replayed_recording,
        ),
        Case("burst of 30 consistent wrong poses", "arm moves at most 0.1 rad", _burst),
        Case(
            "raw poses sweep the left hand into the hip",
            "no command closer to the body than the margin",
            _into_the_body,
        ),
        Case(
            "second raw_trajectory publisher",
            "robot follows one (<= 0.02 rad off), ERROR",
            _second_publisher,
        ),
        Case(
            "restart: arm moved while down, measured NaN + out-of-range joints",
            "starts from the measured pose (clamped, NaN from saved)",
            _restart_partial_measurement,
        ),
        Case(
            "second filter with the same state file",
            "refused: exit 78 naming the file",
            _shared_state_file,
        ),
        Case("filter in namespace /pepper2", "status names tell robots apart", _namespaced_status),
        Case(
            "older panel latched stop: false, newer stop: true; stop; SIGKILL filter",
            "still stopped after the restart; a new release counts",
            _older_panels,
        ),
        Case(
            "stop while the state file cannot be written",
            "ERROR on /diagnostics, stop holds",
            _unsaved_stop,
        ),
        Case(
            "flood: stop false", flood + "; state written <= 3 times", _flood(_send_release, True)
        ),
        Case(
            "flood: enable true", flood + "; state written <= 3 times", _flood(_send_enable, True)
        ),
        Case("flood: head_offset", flood, _flood(_send_offset)),
        Case("flood: head_target", flood, _flood(_send_target)),
        Case("flood: joint_states", flood, _flood(_send_measured)),
        Case("flood: raw_trajectory", flood, _flood(_send_raw)),
        Case("flood: parameter sets", flood, _parameter_flood),
        Case(
            "SIGKILL inference_node twice",
            "raw poses again after each kill (the time to the first is a figure)",
            _respawn,
        ),
    ]

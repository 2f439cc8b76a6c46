"""``audio2pose faults``: attack the live node graph and print what the robot would have done.

The campaign starts the three nodes as supervised processes (:func:`~audio2pose_ros.ros.supervisor.
node_graph`, as ``audio2pose run`` does), plays the part of the rest of the world with one probe
participant (:mod:`~audio2pose_ros.ros.tools.fault_harness`), and runs each case in turn over real
DDS:

- the probe streams a benign pose ``P`` on ``raw_trajectory`` (2 points every 20 ms, like
  inference_node) with ``voice_activity`` true, and plays the robot: it echoes the commanded
  pose back as the measured ``joint_states`` (naoqi_driver publishes the measured state there);
- once the commands have settled on ``P``, the case injects its fault (a bad message, a bad
  parameter, a killed or stopped process, an audio format bomb) and keeps the benign stream up;
- the outcome is read from what the robot receives on ``joint_angles``: the worst deviation from
  ``P`` (rad), finiteness, the joint limits, the largest step against what the velocity limit
  allows, and the gaps between commands; process liveness and resident memory come from /proc.

Each case says what the robot must do and what it did, and passes or fails on that. The table
is the product: ``audio2pose faults`` prints it and exits 1 if any case failed.
"""

from __future__ import annotations

import math
import os
import signal
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import rclpy
import yaml
from audio_common_msgs.msg import AudioData, AudioInfo
from builtin_interfaces.msg import Time
from rclpy.serialization import serialize_message
from std_msgs.msg import Bool

from audio2pose_ros import topics
from audio2pose_ros.files import packaged_mapping
from audio2pose_ros.robot.description import load_robot
from audio2pose_ros.ros.executor import shutdown
from audio2pose_ros.ros.qos import LATCHED_QOS
from audio2pose_ros.ros.supervisor import node_graph
from audio2pose_ros.ros.tools.fault_cases_runtime import impersonated_sigstop_case, runtime_cases
from audio2pose_ros.ros.tools.fault_harness import (
    MAX_COMMAND_GAP_S,
    MAX_DEVIATION_RAD,
    OBSERVE_S,
    STEP_TOLERANCE,
    Campaign,
    CampaignProbe,
    Case,
    Outcome,
)
from audio2pose_ros.ros.tools.process_stats import rss_mb
from audio2pose_ros.timebase import SAMPLE_RATE_HZ

__all__ = ["cases", "run_campaign", "table"]

FEATURES_RSS_LIMIT_MB = 400.0


# --- the cases --------------------------------------------------------------------------------


def _bad_point(value: float, joint: str = "LShoulderPitch") -> Callable[[Campaign], Outcome]:
    def run(c: Campaign) -> Outcome:
        pose = c.pose_a
        bad = pose.copy()
        bad[c.robot.names.index(joint)] = value
        c.probe.raw.publish(c.probe.trajectory(bad[None, :]))
        window = c.probe.observe(OBSERVE_S)
        worst = window.worst_deviation(pose)
        ok = worst <= MAX_DEVIATION_RAD and c.inside_limits(window)
        return Outcome(f"moved at most {worst:.3f} rad", ok, worst)

    return run


def _spike(c: Campaign) -> Outcome:
    pose = c.pose_a
    index = c.robot.names.index("LShoulderPitch")
    bad = pose.copy()
    bad[index] = pose[index] + (3.0 if pose[index] < 0 else -3.0)
    bad[index] = float(np.clip(bad[index], c.robot.lower_rad[index], c.robot.upper_rad[index]))
    c.probe.raw.publish(c.probe.trajectory(bad[None, :]))
    window = c.probe.observe(OBSERVE_S)
    worst = window.worst_deviation(pose)
    return Outcome(f"moved at most {worst:.3f} rad", worst <= MAX_DEVIATION_RAD, worst)


def _all_joints(value: float) -> Callable[[Campaign], Outcome]:
    def run(c: Campaign) -> Outcome:
        pose = c.pose_a
        c.probe.raw.publish(c.probe.trajectory(np.full((1, c.robot.n_joints), value)))
        window = c.probe.observe(1.0)
        worst = window.worst_deviation(pose)
        resumed = c.probe.settle(c.pose_b, timeout_s=5.0)
        ok = worst <= MAX_DEVIATION_RAD and c.inside_limits(window) and resumed
        did = f"moved at most {worst:.3f} rad; " + ("tracks again" if resumed else "FROZEN")
        return Outcome(did, ok, worst)

    return run


def _future_stamp(seconds: float) -> Callable[[Campaign], Outcome]:
    def run(c: Campaign) -> Outcome:
        pose = c.pose_a
        now = c.probe.get_clock().now().nanoseconds + int(seconds * 1e9)
        stamp = Time(sec=max(0, now // 1_000_000_000), nanosec=now % 1_000_000_000)
        far = c.pose_b
        c.probe.raw.publish(c.probe.trajectory(far[None, :], stamp=stamp))
        window = c.probe.observe(0.5)
        worst = window.worst_deviation(pose)
        resumed = c.probe.settle(c.pose_b, timeout_s=5.0)
        ok = worst <= MAX_DEVIATION_RAD and resumed
        did = f"moved {worst:.3f} rad; " + ("later poses tracked" if resumed else "FROZEN")
        return Outcome(did, ok, worst)

    return run


def _huge_message(c: Campaign) -> Outcome:
    pose = c.pose_a
    rows = np.repeat(pose[None, :], 100_000, axis=0)
    # built and serialized first: that takes the probe a second, in which its own benign
    # stream would pause long enough for the filter's watchdog to glide to neutral
    data = serialize_message(c.probe.trajectory(rows))
    c.probe.settle(pose)
    c.probe.raw.publish(data)
    window = c.probe.observe(OBSERVE_S)
    worst, gap = window.worst_deviation(pose), window.longest_gap_s()
    ok = worst <= MAX_DEVIATION_RAD and gap <= MAX_COMMAND_GAP_S
    return Outcome(f"moved {worst:.3f} rad, longest gap {gap * 1e3:.0f} ms", ok, worst)


def _head(kind: str, value: float) -> Callable[[Campaign], Outcome]:
    def run(c: Campaign) -> Outcome:
        pose = c.pose_a
        publisher = c.probe.head_target if kind == "target" else c.probe.head_offset
        publisher.publish(c.probe.joint_state_msg(np.array([value]), names=("HeadYaw",)))
        window = c.probe.observe(OBSERVE_S)
        worst = window.worst_deviation(pose)
        return Outcome(f"head moved {worst:.3f} rad", worst <= MAX_DEVIATION_RAD, worst)

    return run


def _malformed(c: Campaign) -> Outcome:
    pose = c.pose_a
    msg = c.probe.trajectory(pose[None, :])
    msg.joint_names = msg.joint_names[:3]  # too few names for the positions
    c.probe.raw.publish(msg)
    duplicate = c.probe.trajectory(pose[None, :])
    duplicate.joint_names = ["HeadYaw"] * len(duplicate.joint_names)
    c.probe.raw.publish(duplicate)
    window = c.probe.observe(1.0)
    worst = window.worst_deviation(pose)
    alive = c.supervisor.processes["motion_filter_node"].poll() is None
    ok = worst <= MAX_DEVIATION_RAD and alive
    return Outcome(f"moved {worst:.3f} rad, node alive: {alive}", ok, worst)


def _stop_hold(c: Campaign) -> Outcome:
    pose = c.pose_a
    c.probe.stop.publish(Bool(data=True))
    c.probe.spin_for(0.3)
    c.probe.pose = c.pose_b  # generated motion elsewhere, and a head target
    c.probe.head_target.publish(c.probe.joint_state_msg(np.array([0.5]), names=("HeadYaw",)))
    window = c.probe.observe(OBSERVE_S)
    worst = window.worst_deviation(pose)
    c.probe.stop.publish(Bool(data=False))
    c.probe.pose = pose
    c.probe.settle(pose)
    return Outcome(f"moved {worst:.3f} rad while stopped", worst <= 0.02, worst)


def _stop_neutral_head_target(c: Campaign) -> Outcome:
    ok_set, reason = c.probe.set_parameter("stop_behaviour", "neutral")
    if not ok_set:
        return Outcome(f"could not set stop_behaviour: {reason}", False)
    c.probe.stop.publish(Bool(data=True))
    c.probe.spin_for(2.5)  # the glide to neutral ends
    neutral = c.robot.neutral_rad
    c.probe.head_target.publish(c.probe.joint_state_msg(np.array([0.6]), names=("HeadYaw",)))
    window = c.probe.observe(1.0)
    head = np.array([n.startswith("Head") for n in c.robot.names])
    worst = window.worst_deviation(neutral, head)
    c.probe.stop.publish(Bool(data=False))
    c.probe.set_parameter("stop_behaviour", "hold")
    c.probe.settle(c.pose_a)
    return Outcome(f"head moved {worst:.3f} rad while stopped", worst <= 0.02, worst)


def _parameters(c: Campaign) -> Outcome:
    refused = []
    for name, value in (("kalman_q", math.nan), ("rate_hz", 50.0), ("arms_gain", 7.0)):
        ok, reason = c.probe.set_parameter(name, value)
        refused.append(not ok and bool(reason))
    accepted, _ = c.probe.set_parameter("neutral_glide_s", 2)  # an integer for a float
    c.probe.set_parameter("neutral_glide_s", 1.0)
    ok = all(refused) and accepted
    return Outcome(f"bad values refused: {sum(refused)}/3, int for float accepted: {accepted}", ok)


def _restart(
    kill: signal.Signals, stop_first: bool, robot_reports: bool = True
) -> Callable[[Campaign], Outcome]:
    def run(c: Campaign) -> Outcome:
        pose = c.pose_a
        c.probe.robot_reports = robot_reports
        if stop_first:
            c.probe.stop.publish(Bool(data=True))
            c.probe.spin_for(0.5)
        old = c.pid("motion_filter_node")
        start = time.monotonic()
        killed_s = c.probe.get_clock().now().nanoseconds * 1e-9
        os.kill(old, kill)
        if stop_first:  # the sender of the stop goes away too: its latched stop is gone
            c.probe.destroy_publisher(c.probe.stop)
            c.probe.stop = c.probe.create_publisher(Bool, topics.STOP, LATCHED_QOS)
        c.probe.pose = c.pose_b if stop_first else pose
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline and c.pid("motion_filter_node") == old:
            c.probe.spin_for(0.05)
        c.probe.commands.clear()
        if not robot_reports:  # the restarted filter has no measured pose: it commands nothing
            c.probe.spin_for(3.0)
            if len(c.probe.commands):
                c.probe.robot_reports = True
                c.probe.settle(pose)
                return Outcome(f"{len(c.probe.commands)} commands without a measured pose", False)
            c.probe.robot_reports = True  # the robot reports again: the start is from its pose
        window = c.probe.observe_restart(killed_s, timeout_s=30.0, seconds=6.0)
        if not len(window.times_s):
            return Outcome("no commands after the restart", False)
        restarted_s = time.monotonic() - start - 6.0  # to its first command
        worst = window.worst_deviation(pose)
        steps = c.max_step_ratio(window)
        ok = worst <= MAX_DEVIATION_RAD and steps <= STEP_TOLERANCE and c.inside_limits(window)
        did = (
            f"back after {restarted_s:.1f} s; moved {worst:.3f} rad from where it was"
            + ("; still stopped" if stop_first and worst <= MAX_DEVIATION_RAD else "")
            + f"; largest step {steps:.2f} of the velocity limit"
        )
        if stop_first:
            c.probe.stop.publish(Bool(data=False))
        c.probe.robot_reports = True
        c.probe.settle(pose)
        return Outcome(did, ok, worst)

    return run


def _audio_bomb(rate: int) -> Callable[[Campaign], Outcome]:
    def run(c: Campaign) -> Outcome:
        node = "audio_features_node"
        pid = c.pid(node)
        info = AudioInfo(
            channels=1, sample_rate=rate, sample_format="S16LE", bitrate=0, coding_format="wave"
        )
        c.probe.audio_info.publish(info)
        c.probe.spin_for(0.3)
        start = time.monotonic()
        for _ in range(3):
            c.probe.audio.publish(AudioData(data=bytes(200_000)))
            c.probe.spin_for(0.2)
        c.probe.spin_for(1.0)
        rss = rss_mb(c.pid(node))
        alive = c.pid(node) == pid and c.supervisor.processes[node].poll() is None
        c.probe.audio_info.publish(
            AudioInfo(
                channels=1,
                sample_rate=SAMPLE_RATE_HZ,
                sample_format="S16LE",
                bitrate=0,
                coding_format="wave",
            )
        )
        c.probe.spin_for(0.5)
        before = c.probe.features
        for _ in range(20):
            c.probe.audio.publish(AudioData(data=bytes(320)))
            c.probe.spin_for(0.01)
        c.probe.spin_for(1.0)
        recovered = c.probe.features > before
        ok = alive and rss <= FEATURES_RSS_LIMIT_MB and recovered
        did = (
            f"same process: {alive}, {rss:.0f} MB resident, "
            f"{time.monotonic() - start:.1f} s; features after a valid AudioInfo: {recovered}"
        )
        return Outcome(did, ok)

    return run


def cases() -> list[Case]:
    """The campaign, in the order it runs."""
    bad = "cannot move any joint more than 0.1 rad; counted"
    return [
        Case("raw point 90 rad (one arm joint)", bad, _bad_point(90.0)),
        Case("raw point 1e6 rad", bad, _bad_point(1e6)),
        Case("raw point 1e50 rad", bad, _bad_point(1e50)),
        Case("in-range one-frame spike of 3 rad", bad, _spike),
        Case("raw point 1e308 in every joint", bad + "; tracking goes on", _all_joints(1e308)),
        Case("raw point NaN in every joint", bad + "; tracking goes on", _all_joints(math.nan)),
        Case("raw point -inf in every joint", bad + "; tracking goes on", _all_joints(-math.inf)),
        Case("stamp 1e6 s in the future", "rejected; later poses tracked", _future_stamp(1e6)),
        Case("stamp 1000 s in the past", "rejected; later poses tracked", _future_stamp(-1000.0)),
        Case(
            "message of 100,000 points",
            f"bounded work: no gap > {MAX_COMMAND_GAP_S * 1e3:.0f} ms, no jump",
            _huge_message,
        ),
        Case("head_target 1e6", "head moves at most 0.1 rad", _head("target", 1e6)),
        Case("head_offset 1e6", "head moves at most 0.1 rad", _head("offset", 1e6)),
        Case("head_target NaN", "head moves at most 0.1 rad", _head("target", math.nan)),
        Case("malformed trajectories", "dropped; node keeps serving", _malformed),
        Case("stop (hold), then motion + head_target", "nothing moves", _stop_hold),
        Case(
            "stop (neutral), then head_target",
            "head stays at neutral",
            _stop_neutral_head_target,
        ),
        Case(
            "set_parameters: NaN, read-only, out of range; int for float",
            "bad refused with a reason; int accepted",
            _parameters,
        ),
        Case(
            "SIGKILL motion_filter_node",
            "restarts where the robot is: no jump, steps within velocity limits",
            _restart(signal.SIGKILL, stop_first=False),
        ),
        Case(
            "SIGKILL motion_filter_node, robot reports no joint states",
            "commands nothing until the robot reports its pose again, then no jump",
            _restart(signal.SIGKILL, stop_first=False, robot_reports=False),
        ),
        Case(
            "stop, then SIGKILL filter and the stop's sender",
            "still stopped after the restart",
            _restart(signal.SIGKILL, stop_first=True),
        ),
        impersonated_sigstop_case(),  # SIGSTOP the filter while an impostor publishes its status
        Case(
            "AudioInfo sample_rate 1",
            "features node survives, bounded memory, recovers",
            _audio_bomb(1),
        ),
        Case(
            "AudioInfo sample_rate 383999",
            "features node survives, bounded memory, recovers",
            _audio_bomb(383999),
        ),
        *runtime_cases(),  # tracks, start poses, state files, stops, liveness, floods, respawn
    ]


def run_campaign(
    selected: list[Case] | None = None,
    log_dir: Path | None = None,
    progress: Callable[[str], None] = print,
) -> list[tuple[Case, Outcome]]:
    """Start the graph, run the cases, return (case, outcome) pairs."""
    robot = load_robot()
    chosen = selected if selected is not None else cases()
    with tempfile.TemporaryDirectory(prefix="audio2pose_faults_") as tmp:
        state = Path(tmp) / "state" / "filter_state.json"  # alone in its directory
        params = Path(tmp) / "params.yaml"
        document = packaged_mapping("config", "pepper.yaml")
        document.setdefault("motion_filter_node", {}).setdefault("ros__parameters", {})
        document["motion_filter_node"]["ros__parameters"]["state_file"] = str(state)
        params.write_text(yaml.safe_dump(document), encoding="utf-8")
        logs = log_dir or Path(tmp) / "logs"
        with node_graph(params, log_dir=logs) as supervisor:
            rclpy.init()
            probe = CampaignProbe(robot)
            try:
                campaign = Campaign(supervisor, probe, robot, state_file=state)
                progress("waiting for the graph ...")
                if not probe.settle(campaign.pose_a, timeout_s=60.0):
                    raise TimeoutError(f"the graph did not follow the probe (logs: {logs})")
                for case in chosen:
                    # Each case is one fault: its kills must not add to the previous case's
                    # restarts in a row, or the budget gives up on a node mid-campaign.
                    supervisor.budget.forget()
                    probe.settle(campaign.pose_a)
                    try:
                        outcome = case.run(campaign)
                    except Exception as exc:  # a case that breaks is a failed case
                        outcome = Outcome(f"case raised {type(exc).__name__}: {exc}", False)
                    campaign.rows.append((case, outcome))
                    progress(f"{'PASS' if outcome.passed else 'FAIL'}  {case.name}: {outcome.did}")
                return campaign.rows
            finally:
                probe.destroy_node()
                shutdown()


def table(rows: list[tuple[Case, Outcome]]) -> str:
    """The campaign as a Markdown table."""
    lines = [
        "| case | the robot must | it did | result | worst deviation (rad) |",
        "|---|---|---|---|---|",
    ]
    for case, outcome in rows:
        worst = (
            "" if math.isnan(outcome.worst_deviation_rad) else f"{outcome.worst_deviation_rad:.3f}"
        )
        verdict = "pass" if outcome.passed else "FAIL"
        lines.append(f"| {case.name} | {case.must} | {outcome.did} | {verdict} | {worst} |")
    return "\n".join(lines)

"""The node graph against the simulated Pepper over real DDS: speech moves the simulated robot.

``audio2pose run --sim`` starts ``pepper_sim_node`` next to the three nodes: the motion filter
starts from the simulated robot's measured pose, its commands move the simulated joints at the
speed JointAnglesWithSpeed asks for, and the measured joint states follow the commands with a
bounded lag (as the filter's tracking watch measures it) and no arm inside the body.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from audio_common_msgs.msg import AudioInfo
from graph_probe import Probe, diagnostics_of
from sensor_msgs.msg import JointState

from audio2pose_ros.audio.pcm import S16LE_MONO_16K, encode_pcm
from audio2pose_ros.audio.wav import read_wav
from audio2pose_ros.motion.tracking import TRACKING_TOLERANCE_RAD, TrackingWatch
from audio2pose_ros.robot.body import BodyModel
from audio2pose_ros.ros.messages import stamp_s
from audio2pose_ros.ros.supervisor import node_graph
from audio2pose_ros.topics import JOINT_STATES, absolute

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def test_when_speech_plays_against_the_simulated_robot_expect_it_moves_and_tracks(
    tmp_path: Path, probe: Probe, robot, speech_files
):
    measured: list[tuple[float, np.ndarray]] = []

    def on_state(msg: JointState) -> None:
        index = {name: i for i, name in enumerate(msg.name)}
        stamp = stamp_s(msg.header.stamp)
        measured.append((stamp, np.array([msg.position[index[n]] for n in robot.names])))

    probe.create_subscription(JointState, absolute(JOINT_STATES), on_state, 1000)
    samples, _ = read_wav(speech_files[0])
    payload = encode_pcm(samples, S16LE_MONO_16K)
    with node_graph(log_dir=tmp_path, sim=True) as graph:
        probe.info.publish(AudioInfo(**S16LE_MONO_16K.audio_info_fields()))
        probe.wait_until(probe.graph_ready)
        probe.wait_until(lambda: len(measured) > 10)
        probe.warm_up()
        measured.clear()
        probe.play(payload, [3200], bytes_per_s=32000)
        probe.spin_for(1.0)
        assert not any(graph.restarts.values()), "a node died"
        sim_status = diagnostics_of(probe, "pepper_sim_node")

    assert len(measured) > 40 * len(samples) / 16000  # about 50 Hz, like naoqi_driver
    stamps = np.array([t for t, _ in measured])
    positions = np.array([p for _, p in measured])
    assert positions.std(axis=0).max() > 0.02  # the simulated robot moved with the speech
    commands = probe.received["angles"]
    command_t = np.array([stamp_s(m.header.stamp) for m in commands])
    command_p = np.array([m.joint_angles for m in commands])
    # Only the states whose commands in force the probe has all seen: the newest commands may
    # still be on their way to it when it stops listening.
    seen = (stamps >= command_t[0]) & (stamps <= command_t[-1])
    assert seen.sum() > 0.8 * len(stamps)
    # As motion_filter_node's tracking watch measures it (its own TrackingWatch, fed in time
    # order): a measured angle against the range of angles commanded over the lag a robot may
    # have (transport, its controller, a loaded CPU), off by how far it lies outside that range.
    watch, k, off = TrackingWatch(), 0, []
    for t, pose in zip(stamps[seen], positions[seen], strict=True):
        while k < len(command_t) and command_t[k] <= t:
            watch.command(command_p[k], command_t[k])
            k += 1
        watch.measure(pose, t)
        off.append(watch.off_rad)
    # below what the tracking watch reports as a robot not following
    assert np.percentile(off, 95) < TRACKING_TOLERANCE_RAD, np.percentile(off, [50, 95, 100])
    # and most of the time close to the command in force: the lag is short
    last = np.searchsorted(command_t, stamps[seen], side="right") - 1
    error = np.abs(positions[seen] - command_p[last]).max(axis=1)
    assert np.median(error) < TRACKING_TOLERANCE_RAD, np.percentile(error, [50, 95])
    assert BodyModel.load(robot).clearance(positions).min() >= 0.0
    assert int(sim_status["self_collision_steps"]) == 0
    assert int(sim_status["commands_refused"]) == 0

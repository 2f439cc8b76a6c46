"""``audio2pose bag replay`` into the real node graph: the replayed speech comes out as frames.

The three node processes run as ``audio2pose run`` starts them; the replay is the real console
command in its own process. audio_features_node subscribes to ``audio_info`` transient-local
(audio_capture latches it), so a replay that offered it volatile produced no features at all.
"""

from __future__ import annotations

import subprocess
import time
from pathlib import Path

import pytest

from audio2pose_ros.data.bag import AUDIO_TOPIC, read_messages, write_audio_bag
from audio2pose_ros.ros.supervisor import executable_command, node_graph

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def test_when_a_speech_bag_is_replayed_into_the_graph_expect_features_and_poses_out(
    tmp_path: Path, probe, speech
):
    bag = tmp_path / "bag"
    write_audio_bag(speech[:32000], bag)  # 2 s of speech
    chunks = sum(m.topic == AUDIO_TOPIC for m in read_messages(bag))
    with node_graph(log_dir=tmp_path, no_robot=True) as graph:
        probe.wait_until(probe.graph_ready)
        replay = subprocess.Popen(
            [*executable_command("audio2pose"), "bag", "replay", str(bag), "--wait-s", "5"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        probe.wait_until(lambda: replay.poll() is not None, timeout_s=60)

        def frames() -> int:
            return sum(m.layout.dim[0].size for m in probe.received["features"])

        def poses() -> int:
            return sum(len(m.points) for m in probe.received["raw"])

        # 2 s of audio in 10 ms hops: about 200 frames (the first 25 ms window completes later);
        # every frame becomes one pose once inference_node has caught up.
        end = time.monotonic() + 15.0
        while time.monotonic() < end and not (frames() >= 190 and poses() == frames()):
            probe.spin_for(0.1)
        assert not any(graph.restarts.values()), "a node died"
    assert replay.returncode == 0, replay.stderr.read()
    assert f"replayed {chunks + 1} messages on 2 topics" in replay.stdout.read()
    assert frames() >= 190, frames()
    assert poses() == frames()

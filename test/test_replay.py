"""Replay testing: a real speech bag through the live graph equals offline synthesis.

`audio2pose run --play BAG --record OUT` starts the three node processes, publishes the bag's
AudioData / AudioInfo with their recorded timing over DDS and records what the graph sends. The
recorded raw trajectory must equal the offline prediction of the same audio: the only
differences allowed are the float32 transport of the features and the frames that straddle the
silence the player sends while the graph comes up.
"""

import subprocess
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from stateless_model import stateless_checkpoint

from audio2pose_ros.checkpoints.torch_io import load_checkpoint
from audio2pose_ros.data.bag import read_bag_audio, write_audio_bag
from audio2pose_ros.offline.synthesis import predict_normalized
from audio2pose_ros.ros.supervisor import executable_command
from audio2pose_ros.topics import RAW_TRAJECTORY, absolute

pytestmark = [pytest.mark.ros, pytest.mark.slow]
TOLERANCE_RAD = 1e-4  # float32 features over DDS against float64 offline


def recorded_raw_poses(bag: Path, names: tuple[str, ...]) -> np.ndarray:
    rows = []
    with next(bag.glob("*.mcap")).open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, _, _, msg in reader.iter_decoded_messages(topics=[absolute(RAW_TRAJECTORY)]):
            assert tuple(msg.joint_names) == names
            rows += [point.positions for point in msg.points]
    return np.array(rows)


def test_when_speech_bag_replayed_through_graph_expect_offline_trajectory(
    tmp_path: Path, robot, speech_files
):
    from audio2pose_ros.audio.wav import read_wav

    speech = read_wav(speech_files[3])[0]
    model = stateless_checkpoint(tmp_path / "mlp.safetensors", robot, speech)
    bag = tmp_path / "speech_bag"
    write_audio_bag(speech, bag)  # 6 s of speech, irregular chunks
    out = tmp_path / "recorded"
    result = subprocess.run(
        [
            *executable_command("audio2pose"),
            "run",
            "--no-robot",
            "--play",
            str(bag),
            "--record",
            str(out),
            "--log-dir",
            str(tmp_path / "logs"),
            "--model",
            str(model),
        ],
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert result.returncode == 0, result.stderr

    live = recorded_raw_poses(out, robot.names)
    checkpoint = load_checkpoint(model, robot=robot)
    offline = robot.denormalize(predict_normalized(checkpoint, read_bag_audio(bag)))
    # The stream emits every complete window; offline also has python_speech_features' final
    # zero-padded window. Up to two live frames straddle the warm-up silence and the speech.
    expected = len(offline) - 1
    errors = {
        lead: np.abs(live[lead : lead + expected] - offline[:expected]).max()
        for lead in range(3)
        if len(live) >= lead + expected
    }
    lead = min(errors, key=errors.get)
    assert len(live) == lead + expected
    assert errors[lead] < TOLERANCE_RAD, errors
    print(f"lead {lead} frames, max error {errors[lead]:.2e} rad")

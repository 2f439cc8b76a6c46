"""A recording survives SIGKILL: at most about a second is lost, and `bag repair` reads the rest."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

from audio2pose_ros.data.bag import BagWriter, read_messages, repair_bag
from audio2pose_ros.ros.recorder import RECORD_FLUSH_PERIOD_S
from audio2pose_ros.ros.supervisor import executable_command

AUDIO = "audio_common_msgs/msg/AudioData"


def test_when_a_flushing_writer_is_killed_expect_all_but_the_last_period_repaired(tmp_path):
    """A child process writes one small message every 10 ms and is SIGKILLed after 3 s."""
    bag = tmp_path / "killed"
    code = (
        "import sys, time\n"
        "from audio2pose_ros.data.bag import BagWriter\n"
        f"w = BagWriter({str(bag)!r}, flush_period_s={RECORD_FLUSH_PERIOD_S})\n"
        "w.__enter__()\n"
        "data = bytes([0, 1, 0, 0, 4, 0, 0, 0, 1, 2, 3, 4])\n"
        "i = 0\n"
        "while True:\n"
        f"    w.write('/audio/audio', {AUDIO!r}, i * 10_000_000, data)\n"
        "    i += 1\n"
        "    print(i, flush=True)\n"
        "    time.sleep(0.01)\n"
    )
    child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    time.sleep(3.0)
    child.send_signal(signal.SIGKILL)
    written = int(child.stdout.read().split()[-1])
    child.wait()
    assert not (bag / "metadata.yaml").exists()  # killed: rosbag2 never closed it
    counts = repair_bag(bag, tmp_path / "repaired")
    kept = counts["/audio/audio"]
    lost_s = (written - kept) * 0.01
    assert lost_s <= RECORD_FLUSH_PERIOD_S + 0.5, (written, kept)
    assert sum(1 for _ in read_messages(tmp_path / "repaired")) == kept


def test_when_a_bag_closed_normally_expect_repair_to_copy_every_message(tmp_path):
    with BagWriter(tmp_path / "good", flush_period_s=0.0) as bag:
        for i in range(50):
            bag.write("/audio/audio", AUDIO, i, bytes([0, 1, 0, 0, 0, 0, 0, 0]))
    counts = repair_bag(tmp_path / "good", tmp_path / "copy")
    assert counts == {"/audio/audio": 50}


def test_when_bag_repair_runs_from_the_command_line_expect_counts_printed(tmp_path):
    with BagWriter(tmp_path / "good") as bag:
        bag.write("/audio/audio", AUDIO, 1, bytes([0, 1, 0, 0, 0, 0, 0, 0]))
    result = subprocess.run(
        [
            *executable_command("audio2pose"),
            *("bag", "repair", str(tmp_path / "good"), "-o", str(tmp_path / "out")),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    assert "wrote 1 messages on 1 topics" in result.stdout
    assert Path(tmp_path / "out" / "metadata.yaml").is_file()

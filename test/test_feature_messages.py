"""Features messages number their first frame, so a receiver counts the frames lost on the way."""

from __future__ import annotations

import numpy as np
import pytest

from audio2pose_ros.ros.messages import features_to_msg, msg_to_features
from audio2pose_ros.timebase import FrameSequence


def test_when_batches_arrive_in_order_expect_nothing_lost():
    sequence = FrameSequence()
    assert [sequence.observe(first, 5) for first in (0, 5, 10, 15)] == [0, 0, 0, 0]
    assert sequence.lost == 0


def test_when_batches_are_skipped_expect_their_frames_counted_lost():
    sequence = FrameSequence()
    assert sequence.observe(100, 5) == 0  # joined a running stream: nothing known before
    assert sequence.observe(115, 5) == 10  # 105..114 never came
    assert sequence.observe(120, 3) == 0
    assert sequence.observe(200, 1) == 77
    assert sequence.lost == 87


def test_when_the_publisher_restarts_expect_a_new_stream_not_a_loss():
    sequence = FrameSequence()
    sequence.observe(0, 50)
    assert sequence.observe(0, 10) == 0  # back to 0: the publisher started again
    assert sequence.restarts == 1
    assert sequence.observe(20, 10) == 10  # and the new stream is followed
    assert sequence.lost == 10


def test_when_a_batch_is_not_numbered_expect_no_count_across_it():
    sequence = FrameSequence()
    sequence.observe(0, 10)
    assert sequence.observe(None, 10) == 0
    assert sequence.observe(500, 10) == 0  # nothing to compare with after an unnumbered batch
    assert sequence.lost == 0


@pytest.mark.parametrize("first", [None, 0, 7, 10**17])
def test_when_features_are_packed_expect_the_same_frames_label_and_number(first):
    frames = np.arange(12, dtype=np.float32).reshape(3, 4)
    batch = msg_to_features(features_to_msg(frames, "logfbank4", first))
    np.testing.assert_array_equal(batch.frames, frames)
    assert batch.label == "logfbank4"
    assert batch.first_frame == first


@pytest.mark.parametrize(
    "label",
    [
        "frames",
        "",
        "frames from",
        "frames from -3",
        "frames from 1.5",
        "frames from ²",  # a digit to str.isdigit, not to int
        "frames from 9" * 3,
        "frames from " + "9" * 40,  # beyond int64
        "frames from 12 ",
    ],
)
def test_when_the_frames_label_is_not_a_number_expect_an_unnumbered_batch(label):
    msg = features_to_msg(np.zeros((2, 3), np.float32), "logfbank3")
    msg.layout.dim[0].label = label
    batch = msg_to_features(msg)
    assert batch.first_frame is None
    assert batch.frames.shape == (2, 3)

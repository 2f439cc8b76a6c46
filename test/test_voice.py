"""The voice out of the robot, without ROS: framing, delay line, lags, the delay, the NAOqi link.

The NAOqi link is tested against the robot double over NAOqi's real protocol (a ``qi.Session``
serving the fake ALAudioDevice on 127.0.0.1, a second one connecting to it).
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.voice.delay import (
    GAP_S,
    PAUSE_STRETCH,
    SPEECH_STRETCH,
    DelayedCommands,
    DelayLine,
    SpeakerQueue,
)
from audio2pose_ros.voice.framing import (
    MAX_FRAMES_PER_CALL,
    MIC_CHANNELS,
    MIC_FRAMES,
    stereo_blocks,
    stereo_pcm,
)
from audio2pose_ros.voice.lag import ChunkPairing, motion_lag, sound_lag
from audio2pose_ros.voice.naoqi import NaoqiVoiceOut, parse_voice_out
from audio2pose_ros.voice.robot_double import (
    FakeAudioDevice,
    RobotLoudspeaker,
    RobotMicrophones,
    serve_audio_device,
)
from audio2pose_ros.voice.sync import (
    DEFAULTS_S,
    MIN_MEASUREMENTS,
    TARGET_LEAD_S,
    SyncEstimator,
    voice_delay_s,
)


def wait_for(condition, timeout_s: float = 30.0) -> None:
    """Poll ``condition`` until it holds; a timeout only ends a hung test."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise TimeoutError("condition not met")
        time.sleep(0.01)


# --- framing ----------------------------------------------------------------------------------


def test_when_mono_is_framed_expect_interleaved_16_bit_stereo_with_both_channels_equal():
    mono = np.array([0.0, 0.5, -0.5, 1.0, -1.0, 2.0, np.nan], dtype=np.float32)
    pcm = np.frombuffer(stereo_pcm(mono), dtype="<i2").reshape(-1, 2)
    assert pcm.shape == (7, 2)
    assert (pcm[:, 0] == pcm[:, 1]).all()
    assert pcm[:, 0].tolist() == [0, 16384, -16384, 32767, -32767, 32767, 0]


def test_when_a_long_voice_is_framed_expect_calls_of_at_most_16384_frames_and_none_lost():
    mono = np.linspace(-0.5, 0.5, 2 * MAX_FRAMES_PER_CALL + 123)
    calls = list(stereo_blocks(mono))
    assert [n for n, _ in calls] == [MAX_FRAMES_PER_CALL, MAX_FRAMES_PER_CALL, 123]
    assert all(len(buffer) == 4 * n for n, buffer in calls)


# --- delay line -------------------------------------------------------------------------------


def test_when_chunks_wait_expect_each_released_delay_after_arrival_in_order():
    line = DelayLine(16000)
    line.push(np.ones(320), 10.0)
    line.push(2 * np.ones(320), 10.02)
    assert line.due(10.09, 0.1) == []
    first = line.due(10.10, 0.1)
    assert [c.arrival_s for c in first] == [10.0]
    assert [c.arrival_s for c in line.due(10.2, 0.1)] == [10.02]
    assert line.released_samples == 640


def test_when_the_line_overflows_expect_the_oldest_dropped_and_counted():
    line = DelayLine(16000, max_s=0.05)
    for k in range(5):
        line.push(np.zeros(320), float(k))  # 20 ms each, 100 ms in all
    assert line.held_s <= 0.05
    assert line.dropped_s == pytest.approx(0.06)
    assert [c.arrival_s for c in line.due(100.0, 0.0)] == [3.0, 4.0]  # the newest 40 ms


def test_when_the_loudspeaker_queue_grows_expect_pauses_cut_first_then_any_chunk_skipped():
    queue = SpeakerQueue(16000, max_backlog_s=0.04, max_speech_backlog_s=0.15)
    loud, quiet = 0.3 * np.ones(320), np.zeros(320)

    def start(now_s: float, samples: np.ndarray) -> float | None:
        queued = queue.offer(now_s, samples)
        return None if queued is None else queued.start_s

    starts = [start(10.0, loud) for _ in range(5)]  # 100 ms arrive at once
    assert starts == pytest.approx([10.0, 10.02, 10.04, 10.06, 10.08])  # played back to back
    assert start(10.0, quiet) is None  # a pause while 100 ms wait: skipped
    assert start(10.0, loud) == pytest.approx(10.1)  # speech is still played
    later = [start(10.0, loud) for _ in range(4)]  # beyond 150 ms: skipped too
    assert [s is None for s in later] == [False, False, True, True]
    assert queue.skipped_samples == 320
    assert queue.speech_skipped_samples == 640
    assert start(11.0, quiet) == 11.0  # the queue has drained: nothing is skipped
    # 50 ms queued: a pause is cut by the 10 ms beyond 40 ms, and the queue holds 40 ms again
    queue = SpeakerQueue(16000, max_backlog_s=0.04)
    for samples in (loud, loud, loud[:160]):
        queue.offer(20.0, samples)
    cut = queue.offer(20.0, quiet)
    assert cut is not None
    assert len(cut.samples) == 320 - 160
    assert queue.skipped_samples == 160
    assert queue.backlog_s(20.0 + 0.05) == pytest.approx(0.01)  # what was queued, then its rest
    assert queue.standing_s(20.0) == pytest.approx(0.04)


# --- lags -------------------------------------------------------------------------------------


def _wiggle(times: np.ndarray, n_joints: int = 3) -> np.ndarray:
    rng = np.random.default_rng(0)
    freqs, phases = rng.uniform(0.5, 3.0, n_joints), rng.uniform(0, 6, n_joints)
    return np.stack(
        [0.3 * np.sin(2 * np.pi * f * times + p) for f, p in zip(freqs, phases, strict=True)], 1
    )


@pytest.mark.parametrize("lag_s", [0.0, 0.037, 0.15, 0.31])
def test_when_a_trajectory_follows_another_expect_its_lag_measured(lag_s):
    t_a = np.arange(0.0, 6.0, 0.01)
    t_b = np.arange(0.003, 6.0, 0.02)  # another rate and phase, like joint_states at 50 Hz
    lag = motion_lag(t_a, _wiggle(t_a), t_b, _wiggle(t_b - lag_s), 0.6)
    assert lag.score > 0.9
    assert lag.lag_s == pytest.approx(lag_s, abs=0.006)


def test_when_the_trajectories_do_not_move_expect_no_measurement():
    t = np.arange(0.0, 3.0, 0.01)
    lag = motion_lag(t, np.zeros((len(t), 3)), t, np.zeros((len(t), 3)), 0.5)
    assert math.isnan(lag.lag_s)
    assert lag.score == 0.0


def _speechlike(seconds: float, rate: int, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    n = int(seconds * rate)
    syllables = np.repeat(rng.uniform(0, 1, int(seconds * 5) + 1) > 0.4, rate // 5)[:n]
    return 0.3 * rng.normal(size=n) * syllables


@pytest.mark.parametrize("lag_s", [0.0, 0.05, 0.2])
def test_when_the_microphones_hear_the_voice_expect_the_loudspeaker_lag_measured(lag_s):
    voice = _speechlike(4.0, 16000)
    sent = [(100.0 + k * 0.02, voice[k * 320 : (k + 1) * 320]) for k in range(len(voice) // 320)]
    t48 = 100.0 + lag_s + np.arange(int(4.0 * 48000)) / 48000
    mic = np.interp(t48 - lag_s, 100.0 + np.arange(len(voice)) / 16000, voice) * 0.5
    mic += np.random.default_rng(2).normal(0, 0.004, len(mic))
    heard = [(float(t48[k]), mic[k : k + 8192]) for k in range(0, len(mic), 8192)]
    lag = sound_lag(sent, 16000, heard, 48000, 1.0)
    assert lag.score > 0.8
    assert lag.lag_s == pytest.approx(lag_s, abs=0.004)


@pytest.mark.parametrize("seed", [5, 6, 8])
def test_when_louder_speech_follows_the_voice_compared_expect_its_own_lag_not_a_long_one(seed):
    # the offset's windows: 2 s of voice sent against 3.5 s of microphones, which also hear
    # the louder voice sent after those 2 s; every lag must be judged on the same 2 s, or a
    # long lag on a short overlap wins by chance
    voice = _speechlike(10.0, 16000, seed)
    voice[:64000] *= 0.2
    sent = [(2.0 + k * 0.02, voice[32000 + k * 320 : 32000 + (k + 1) * 320]) for k in range(100)]
    t48 = 2.0 + np.arange(int(3.5 * 48000)) / 48000
    mic = 0.5 * np.interp(t48 - 0.15, np.arange(len(voice)) / 16000, voice)
    mic += np.random.default_rng(9).normal(0, 0.004, len(mic))
    heard = [(float(t48[k]), mic[k : k + 8192]) for k in range(0, len(mic), 8192)]
    lag = sound_lag(sent, 16000, heard, 48000, 1.5)
    assert lag.score > 0.9
    assert lag.lag_s == pytest.approx(0.15, abs=0.008)


def test_when_poses_answer_chunks_expect_each_paired_with_the_newest_chunk_before_it():
    pairing = ChunkPairing()
    for t in (1.000, 1.020, 1.040):
        pairing.chunk(t)
    pairing.poses(1.045)  # the chunk of 1.040; the two before it stay unanswered and go
    pairing.chunk(1.060)
    pairing.poses(1.063)
    assert list(pairing.latencies_s) == pytest.approx([0.005, 0.003])


# --- the delay --------------------------------------------------------------------------------


def test_when_the_motion_path_is_slower_expect_the_voice_held_back_to_lead_by_the_target():
    assert voice_delay_s(0.08, 0.15, 0.05) == pytest.approx(0.08 + 0.15 - 0.05 + TARGET_LEAD_S)
    assert voice_delay_s(0.0, 0.0, 0.5) == 0.0  # never negative: the voice cannot be earlier


def test_when_nothing_is_measured_expect_the_documented_defaults_said_so():
    sync = SyncEstimator(16000)
    sync.update()
    assert not any(part.measured for part in sync.parts.values())
    assert [p.value_s for p in sync.parts.values()] == list(DEFAULTS_S.values())
    assert "default: not measured" in sync.parts["execution"].describe()


def test_when_the_robot_lags_its_commands_expect_its_latency_measured_once_measured_thrice():
    sync = SyncEstimator(16000)
    t_cmd = np.arange(0.0, 5.0, 0.01)
    t_meas = np.arange(0.0, 5.0, 0.02)
    for t, row in zip(t_cmd, _wiggle(t_cmd), strict=True):
        sync.on_commanded(float(t), row)
    for t, row in zip(t_meas, _wiggle(t_meas - 0.15), strict=True):
        sync.on_measured(float(t), row)
    for _ in range(MIN_MEASUREMENTS - 1):
        sync.update()
    assert not sync.parts["execution"].measured  # too few measurements: the default still
    assert sync.delay_s == pytest.approx(voice_delay_s(*DEFAULTS_S.values()))
    sync.update()
    assert sync.parts["execution"].measured
    assert sync.parts["execution"].value_s == pytest.approx(0.15, abs=0.01)
    assert sync.delay_s == pytest.approx(sync.target_delay_s())
    assert sync.delay_s - voice_delay_s(*DEFAULTS_S.values()) == pytest.approx(
        sync.parts["execution"].value_s - DEFAULTS_S["execution"]
    )


def test_when_one_filter_lag_is_an_outlier_expect_the_graph_latency_untouched_by_it():
    # the motion filter's start gives one wild lag; the later updates measure no filter lag
    # (too little motion) or the true one: the outlier is one measurement among them, not
    # repeated at every update until it rules the median
    sync = SyncEstimator(16000)
    for k in range(10):
        sync.on_chunk(k * 0.02)
        sync.on_raw(k * 0.02 + 0.004, k * 0.02, np.zeros(3))
    sync.apply({"filter": 0.49})
    for _ in range(6):
        sync.apply({})  # nothing measured: nothing added
    assert len(sync.parts["graph"].measurements) == 1
    assert not sync.parts["graph"].measured
    for _ in range(MIN_MEASUREMENTS):
        sync.apply({"filter": 0.1})
    assert sync.parts["graph"].value_s == pytest.approx(0.104)


def _voice_out(line: DelayLine, chunks: list[np.ndarray], targets: list[float]) -> list[float]:
    """When each sample is played, pushing ``chunks`` 20 ms apart and serving the line every
    1 ms with ``targets[k]`` asked for during chunk k; a released chunk plays from its release,
    or once what was released before it has played (as a loudspeaker plays them)."""
    played: list[float] = []
    end = -math.inf
    for tick in range(20 * len(chunks) + 500):
        now, k = 0.001 * tick, min(tick // 20, len(chunks) - 1)
        if tick % 20 == 0 and tick // 20 < len(chunks):
            line.push(chunks[k], now)
        for out in line.due(now, targets[k]):
            quiet = not np.abs(out.samples).any()
            assert abs(len(out.samples) - 320) <= round(
                (PAUSE_STRETCH if quiet else SPEECH_STRETCH) * 320
            )
            start = max(now, end)
            played.extend(start + np.arange(len(out.samples)) / line.rate_hz)
            end = start + len(out.samples) / line.rate_hz
    return played


def test_when_the_delay_asked_for_changes_while_speaking_expect_it_moved_in_pauses_without_gap():
    loud, quiet = 0.3 * np.ones(320), np.zeros(320)
    # 4 s of speech with a 60 ms pause every second (as between phrases)
    speech = [quiet if k % 50 in (47, 48, 49) else loud for k in range(200)]
    line = DelayLine(16000)
    targets = [0.1] * 25 + [0.12] * 75 + [0.09] * 100  # calibration: +20 ms, then -30 ms
    played = np.asarray(_voice_out(line, speech, targets))
    # no gap and no burst: the loudspeaker never waits and never runs behind what it was given
    # (each sample plays one period after the last, within the 1 ms serving period)
    spacing = np.diff(played)
    assert spacing.max() < 1 / 16000 + 0.001
    assert spacing.min() > 0.0
    # speech is never stretched (its pitch, and a pure delay for the echo canceller): only the
    # pauses took the change, and the delay reached each target by the end
    ends = np.cumsum([0] + [len(chunk) for chunk in speech])
    assert line.delay_s == pytest.approx(0.09, abs=1 / 16000)
    assert played[0] == pytest.approx(0.1, abs=0.0015)  # within the 1 ms serving period
    assert played[-1] - (199 * 0.02 + 319 / 16000) == pytest.approx(0.09, abs=0.0015)
    assert line.released_samples == len(played) == ends[-1] + line.stretched_samples
    assert line.stretched_samples == -round(0.01 * 16000)


def test_when_the_operator_speaks_without_a_pause_expect_the_speech_never_stretched():
    speech = [0.3 * np.ones(320) for _ in range(100)]
    line = DelayLine(16000)
    played = np.asarray(_voice_out(line, speech, [0.1] * 20 + [0.15] * 80))
    assert line.stretched_samples == 0
    assert line.delay_s == pytest.approx(0.1, abs=1 / 16000)  # waits for a pause
    assert len(played) == 100 * 320


def test_when_the_voice_pauses_expect_the_delay_to_move_faster_and_after_a_gap_at_once():
    loud, quiet = 0.3 * np.ones(320), np.zeros(320)
    line = DelayLine(16000)
    line.push(loud, 0.0)
    assert [len(c.samples) for c in line.due(0.1, 0.1)] == [320]
    line.push(loud, 0.02)
    (speech,) = line.due(0.2, 0.3)
    assert len(speech.samples) == 320  # speech is not stretched
    line.push(quiet, 0.04)
    (pause,) = line.due(0.3, 0.3)
    assert len(pause.samples) == 320 + round(PAUSE_STRETCH * 320)
    # the operator stops talking: after the gap, the next word takes the delay asked for,
    # shortening the silence by at most the gap
    line.push(loud, 0.06 + GAP_S + 0.5)
    assert line.due(0.06 + GAP_S + 0.5 + 0.0049, 0.005) == []
    assert len(line.due(0.06 + GAP_S + 0.5 + 0.005, 0.005)[0].samples) == 320
    assert line.delay_s == 0.005


def test_when_the_node_is_held_up_once_expect_the_voice_back_on_its_delay_at_the_next_pause():
    # the node's 1 ms release ticks stop for 25 ms once (a loaded machine): the chunks due then
    # go out together and the loudspeaker, playing back to back, holds every later one 25 ms
    # longer for as long as the operator talks; its wait is taken off the delay line's delay,
    # which the pauses between phrases (60 ms a second) give back
    rate = 16000
    line, queue, sync = DelayLine(rate), SpeakerQueue(rate), SyncEstimator(rate)
    held_back: list[float] = []  # from each chunk's arrival to when it starts playing
    for tick in range(5000):
        now = 0.001 * tick
        if tick % 20 == 0 and tick < 4000:
            pause = (tick // 20) % 50 in (47, 48, 49)
            line.push(np.zeros(320) if pause else 0.3 * np.ones(320), now)
        if 1000 <= tick < 1025:
            continue
        for chunk in line.due(now, sync.line_delay_s(queue.standing_s(now))):
            queued = queue.offer(now, chunk.samples)
            assert queued is not None
            sync.on_sent(queued.start_s, queued.samples, queued.start_s - now)
            held_back.append(queued.start_s - chunk.arrival_s)
    assert held_back[40] == pytest.approx(sync.delay_s, abs=1e-6)
    assert max(held_back) > sync.delay_s + 0.015  # the chunk due in the stall, and those after
    assert held_back[-1] == pytest.approx(sync.delay_s, abs=0.002)  # back after a pause


@pytest.mark.parametrize("held_up_ms", [60, 150, 400])
def test_when_the_node_is_held_up_with_the_voice_arriving_after_expect_it_late_never_early(
    held_up_ms: int,
):
    # the node stops altogether (its release ticks and its voice callback): the chunks spoken
    # meanwhile all arrive when it resumes, as if after a pause. They are the voice coming late:
    # the loudspeaker's queue holds them and sheds pauses until the voice is back on its delay,
    # never ahead of it (a voice ahead of the motion is the error people notice first)
    rate = 16000
    line, queue, sync = DelayLine(rate), SpeakerQueue(rate), SyncEstimator(rate)
    spoken: list[tuple[float, np.ndarray]] = []  # when each chunk was spoken
    for k in range(250):
        pause = k % 50 in (47, 48, 49) or k % 17 == 16
        spoken.append((0.02 * k, np.zeros(320) if pause else 0.3 * np.ones(320)))
    held_back: list[float] = []  # from when each chunk was spoken to when it starts playing
    out = 0  # chunks out of the line, played or skipped
    waiting = list(spoken)
    for tick in range(6000):
        now = 0.001 * tick
        if 1500 <= tick < 1500 + held_up_ms:
            continue
        while waiting and waiting[0][0] <= now:
            line.push(waiting.pop(0)[1], now)
        for chunk in line.due(now, sync.line_delay_s(queue.standing_s(now))):
            queued = queue.offer(now, chunk.samples)
            if queued is not None:
                sync.on_sent(queued.start_s, queued.samples, queued.start_s - now)
                held_back.append(queued.start_s - spoken[out][0])
            out += 1
    assert out == len(spoken)
    assert max(held_back) >= sync.delay_s + 0.8 * held_up_ms * 1e-3  # late after the hold-up
    assert min(held_back) >= sync.delay_s - 0.002  # never early (1 ms ticks)
    assert held_back[-1] == pytest.approx(sync.delay_s, abs=0.002)  # back on its delay


# --- the robot double and the NAOqi link, over NAOqi's real protocol ---------------------------


@pytest.fixture
def robot_audio():
    speaker = RobotLoudspeaker(0.0, time.time)
    device = FakeAudioDevice(speaker)
    session, url = serve_audio_device("tcp://127.0.0.1:0", device)
    yield device, speaker, url
    session.close()


def test_when_the_voice_is_sent_expect_the_fake_audio_device_gets_every_frame_at_the_rate(
    robot_audio,
):
    device, speaker, url = robot_audio
    voice = np.clip(_speechlike(1.0, 16000), -1, 1)
    link = NaoqiVoiceOut(url, 16000)
    link.start()
    try:
        wait_for(lambda: link.status().connected)
        chunks = np.array_split(voice, 50)
        for chunk in chunks:
            link.send(chunk)
        wait_for(lambda: link.status().frames_sent == len(voice))
    finally:
        link.stop()
    assert device.rate_hz == 16000
    assert device.refused == 0
    assert speaker.frames_played == len(voice)
    played = speaker.played_audio()
    assert np.abs(played - np.round(voice * 32767) / 32768).max() < 1e-6  # the same samples


def test_when_the_voice_is_flushed_expect_nothing_more_heard_and_the_robot_queue_dropped(
    robot_audio,
):
    device, speaker, url = robot_audio
    voice = np.clip(_speechlike(3.0, 16000), -1, 1)
    link = NaoqiVoiceOut(url, 16000, max_queue_s=5.0)
    link.start()
    try:
        wait_for(lambda: link.status().connected)
        link.send(voice)
        wait_for(lambda: link.status().frames_sent == len(voice))  # queued at the robot
        now = time.time()
        assert np.abs(speaker.heard(now + 1.0, now + 2.0, 16000)).max() > 0.01  # still to play
        link.flush()  # the operator mutes
        wait_for(lambda: link.status().flushes == 1)
        now = time.time()
        assert np.abs(speaker.heard(now + 0.05, now + 3.0, 16000)).max() == 0.0
        link.send(voice[:1600])  # unmuted: the voice plays again
        wait_for(lambda: link.status().frames_sent == len(voice) + 1600)
    finally:
        link.stop()
    assert device.flushes == 1


def test_when_the_device_is_asked_wrong_expect_it_refuses_as_alaudiodevice_does(robot_audio):
    import qi

    device, speaker, url = robot_audio
    session = qi.Session()
    session.connect(url)
    remote = session.service("ALAudioDevice")
    assert remote.sendRemoteBufferToOutput(2, b"\x00" * 8) is False  # no output rate yet
    with pytest.raises(RuntimeError):
        remote.setParameter("outputSampleRate", 12345)
    remote.setParameter("outputSampleRate", 48000)
    assert remote.sendRemoteBufferToOutput(3, b"\x00" * 8) is False  # not 3 stereo frames
    assert remote.sendRemoteBufferToOutput(16385, b"\x00" * 16385 * 4) is False
    assert remote.sendRemoteBufferToOutput(2, b"\x00" * 8) is True
    session.close()
    assert device.refused == 4
    assert device.calls == 1
    assert speaker.frames_played == 2


def test_when_naoqi_is_lost_and_back_expect_reported_retried_and_the_caller_never_waits():
    speaker = RobotLoudspeaker(0.0, time.time)
    device = FakeAudioDevice(speaker)
    session, url = serve_audio_device("tcp://127.0.0.1:0", device)
    link = NaoqiVoiceOut(url, 16000, retry_s=0.05)
    link.start()
    try:
        wait_for(lambda: link.status().connected)
        session.close()  # the robot goes away
        for _ in range(200):  # 4 s of voice into a 1 s queue while nothing answers: all return
            link.send(np.zeros(320))
        wait_for(lambda: not link.status().connected)
        lost = link.status()
        assert lost.failures >= 1
        assert lost.last_error
        assert lost.queued_s <= 1.0 + 1e-9  # bounded
        session, _ = serve_audio_device(url, device)  # the robot is back at the same address
        wait_for(lambda: link.status().connected and link.status().connections == 2)
        link.send(np.zeros(320))
        wait_for(lambda: link.status().frames_sent >= 320)
    finally:
        link.stop()
        session.close()
    final = link.status()
    assert final.dropped_s > 0.0  # what could not be played in step was dropped, and counted


def test_when_a_voice_out_is_named_expect_it_parsed_or_refused_clearly():
    assert parse_voice_out("naoqi:tcp://10.0.0.5:9559").url == "tcp://10.0.0.5:9559"
    assert parse_voice_out("naoqi:10.0.0.5").url == "tcp://10.0.0.5:9559"
    assert parse_voice_out("topic").kind == "topic"
    for bad in ("naoqi:", "naoqi:tcp://host:99999", "speaker", "naoqi:http://h:1"):
        with pytest.raises(ConfigurationError, match="expected 'off', 'topic'"):
            parse_voice_out(bad)


# --- the rest of the robot double ------------------------------------------------------------


def test_when_the_loudspeaker_plays_expect_the_microphones_hear_it_after_its_latency():
    now = [100.0]
    speaker = RobotLoudspeaker(0.15, lambda: now[0])
    microphones = RobotMicrophones(speaker, start_s=100.0)
    speaker.play(0.8 * np.ones(1600), 16000)  # 100 ms of a loud tone at t = 100 s
    buffers = microphones.due(100.0 + 2 * MIC_FRAMES / 48000)
    assert len(buffers) == 2
    assert buffers[0][1].shape == (MIC_FRAMES, MIC_CHANNELS)
    signal = np.concatenate([pcm.mean(axis=1) for _, pcm in buffers]) / 32768.0
    loud = np.flatnonzero(np.abs(signal) > 0.2)
    assert loud[0] / 48000 == pytest.approx(0.15, abs=1e-3)
    assert (loud[-1] - loud[0] + 1) / 48000 == pytest.approx(0.1, abs=1e-3)


def test_when_commands_arrive_expect_them_taken_after_the_execution_latency_in_order():
    delayed: DelayedCommands[str] = DelayedCommands(0.15)
    delayed.push(1.0, "a")
    delayed.push(1.01, "b")
    assert delayed.due(1.149) == []
    assert delayed.due(1.15) == ["a"]
    assert delayed.due(2.0) == ["b"]


@pytest.mark.ros
def test_when_the_operator_mutes_expect_the_voice_node_to_flush_what_naoqi_queued(
    robot_audio, tmp_path, monkeypatch
):
    from rclpy.parameter import Parameter

    from audio2pose_ros.ros.nodes.voice_out_node import VoiceOutNode
    from audio2pose_ros.ros.player import rclpy_session

    device, _, url = robot_audio
    monkeypatch.setenv("ROS_HOME", str(tmp_path))
    with rclpy_session(["--ros-args", "-p", f"voice_out:=naoqi:{url}"]):
        node = VoiceOutNode()
        try:
            wait_for(lambda: node.naoqi is not None and node.naoqi.status().connected)
            assert node.set_parameters([Parameter("muted", value=True)])[0].successful
            wait_for(lambda: device.flushes == 1)
            # muted again (the console sets its choice again after a restart): nothing more
            assert node.set_parameters([Parameter("muted", value=True)])[0].successful
            assert node.set_parameters([Parameter("muted", value=False)])[0].successful
            time.sleep(0.3)
            assert node.naoqi.status().flushes == 1
        finally:
            node.destroy_node()

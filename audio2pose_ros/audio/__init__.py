"""ROS-free audio front end: bytes to 16 kHz samples to features (seed 003 sections 3.2, 4.2.2).

- :mod:`~audio2pose_ros.audio.pcm`: AudioData bytes as AudioInfo describes them -> 16 kHz mono
  float32 (any chunking), within documented format limits;
- :mod:`~audio2pose_ros.audio.resample`: the streaming polyphase resampler it uses;
- :mod:`~audio2pose_ros.audio.wav`: WAV files through a bounded RIFF reader;
- :mod:`~audio2pose_ros.audio.source`: the features node's guarded input (audio_common
  AudioInfo/AudioData or naoqi AudioBuffer, per-message and per-second caps);
- :mod:`~audio2pose_ros.audio.dsp`: mel filter bank, DCT, lifter, window, pre-emphasis, deltas;
- :mod:`~audio2pose_ros.audio.features`: feature sets (LogFB, MFCC) and offline extraction;
- :mod:`~audio2pose_ros.audio.streaming`: the same features chunk by chunk;
- :mod:`~audio2pose_ros.audio.normalize`: per-speaker z-normalisation;
- :mod:`~audio2pose_ros.audio.vad`: the energy voice-activity detector.
"""

"""ROS-free audio front end: PCM decoding (seed 003 section 4.2.2) and features (section 3.2).

:mod:`~audio2pose_ros.audio.pcm` turns PCM bytes (AudioData, WAV files) into 16 kHz mono
float32 samples within documented limits; :mod:`~audio2pose_ros.audio.source` applies it to
audio_common AudioInfo/AudioData or naoqi AudioBuffer messages with per-message and per-second
caps; :mod:`~audio2pose_ros.audio.features` turns samples into LogFB/MFCC features, offline or
streaming, with per-speaker z-normalisation.
"""

from audio2pose_ros.audio.features import (
    FeatureNormalizer,
    FeatureSpec,
    StreamingFeatureExtractor,
    dct_matrix,
    delta,
    extract_features,
    hz_to_mel,
    mel_filterbank,
    mel_to_hz,
)
from audio2pose_ros.audio.pcm import (
    MAX_CHANNELS,
    MAX_SAMPLE_RATE_HZ,
    MIN_SAMPLE_RATE_HZ,
    InvalidAudio,
    PcmDecoder,
    PcmFormat,
    PolyphaseResampler,
    UnsupportedAudioFormat,
    encode_pcm,
    read_wav,
)
from audio2pose_ros.audio.source import AudioDropped, AudioInput, AudioInputSettings

__all__ = [
    "MAX_CHANNELS",
    "MAX_SAMPLE_RATE_HZ",
    "MIN_SAMPLE_RATE_HZ",
    "AudioDropped",
    "AudioInput",
    "AudioInputSettings",
    "FeatureNormalizer",
    "FeatureSpec",
    "InvalidAudio",
    "PcmDecoder",
    "PcmFormat",
    "PolyphaseResampler",
    "StreamingFeatureExtractor",
    "UnsupportedAudioFormat",
    "dct_matrix",
    "delta",
    "encode_pcm",
    "extract_features",
    "hz_to_mel",
    "mel_filterbank",
    "mel_to_hz",
    "read_wav",
]

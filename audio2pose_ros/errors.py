"""The errors audio2pose_ros raises on purpose: bad input, bad files, bad configuration.

Every error the package raises for something a user can fix derives from
:class:`Audio2PoseError`. The command line turns exactly these into one clear line (exit status
1, or 2 for :class:`UsageError`); anything else is a bug and is reported as one, with its
traceback under ``--debug``. Nodes treat :class:`ConfigurationError` at start-up as "do not
restart me": they exit with :data:`EXIT_CONFIGURATION_ERROR`.
"""

from __future__ import annotations

__all__ = [
    "EXIT_CONFIGURATION_ERROR",
    "Audio2PoseError",
    "ConfigurationError",
    "InputError",
    "InvalidAudio",
    "UnsupportedAudioFormat",
    "UsageError",
    "short_repr",
    "short_text",
]

# sysexits.h EX_CONFIG: a node cannot run with its configuration; supervisors never respawn it
EXIT_CONFIGURATION_ERROR = 78


class Audio2PoseError(Exception):
    """Base of every expected error: the message names the file, value or option at fault."""


class ConfigurationError(Audio2PoseError):
    """A parameter, setting or robot description is unusable (fix the configuration)."""


class InputError(Audio2PoseError):
    """Data handed to the package (a file, a message, a sample) cannot be used."""


class UsageError(Audio2PoseError):
    """A command-line option or combination of options is invalid (exit status 2)."""


class UnsupportedAudioFormat(InputError):  # noqa: N818 (name fixed by the node API)
    """An AudioInfo field or a WAV header names an audio format the decoder cannot handle."""


class InvalidAudio(InputError):  # noqa: N818 (name fixed by the node API)
    """Audio data that cannot be decoded as samples (NaN or inf in F32LE, a broken WAV file)."""


def short_text(text: str, limit: int) -> str:
    """``text`` cut to ``limit`` characters, saying how long it was, for text that quotes input.

    A message field, a parameter value or a file's entry may be megabytes long; an error or a
    status that quotes it whole floods the log and every reply that carries it.
    """
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def short_repr(value: object, limit: int = 40) -> str:
    """``repr(value)`` cut to ``limit`` characters (:func:`short_text`), for errors."""
    return short_text(repr(value), limit)

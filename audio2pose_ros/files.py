"""Files named by users, read as untrusted input: regular files only, bounded in size.

A path given to the package (a data set's index, a clip, an importer's input, a YAML file) may
name a directory, a FIFO that never ends (reading it would hang), a device such as ``/dev/zero``
(reading it would fill the memory) or a file far larger than what it claims to be.
:func:`regular_file` refuses what is not a regular file before anything opens it, and
:func:`read_bounded` reads at most a cap, each with one line naming the file and the problem.
"""

from __future__ import annotations

import stat
from pathlib import Path

from audio2pose_ros.errors import Audio2PoseError

__all__ = ["read_bounded", "regular_file"]


def regular_file(path: str | Path, what: str, error: type[Audio2PoseError]) -> Path:
    """``path`` as a Path, after checking that it is an existing regular file.

    Symbolic links are followed: a link to a regular file is one, a link to a device is not.

    Raises:
        Audio2PoseError: ``error`` for a missing path, a directory, a special file or a path
            that cannot be examined.
    """
    file = Path(path)
    try:
        mode = file.stat().st_mode
    except FileNotFoundError:
        raise error(f"{file}: {what} file not found") from None
    except OSError as exc:
        raise error(f"{file}: cannot access {what} file ({exc.strerror or exc})") from None
    if stat.S_ISDIR(mode):
        raise error(f"{file}: is a directory, expected a {what} file")
    if not stat.S_ISREG(mode):
        raise error(f"{file}: not a regular file, expected a {what} file")
    return file


def read_bounded(
    path: str | Path, what: str, error: type[Audio2PoseError], max_bytes: int
) -> bytes:
    """The bytes of a regular file of at most ``max_bytes`` (:func:`regular_file` first).

    Raises:
        Audio2PoseError: ``error`` for what :func:`regular_file` refuses, a file larger than
            ``max_bytes`` (refused before it is read) or one that cannot be read.
    """
    file = regular_file(path, what, error)
    try:
        with file.open("rb") as stream:
            raw = stream.read(max_bytes + 1)
    except OSError as exc:
        raise error(f"{file}: cannot read ({exc.strerror or exc})") from None
    if len(raw) > max_bytes:
        raise error(f"{file}: larger than {max_bytes} bytes, not a {what} file")
    return raw

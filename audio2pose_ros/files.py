"""Files named by users, read as untrusted input: regular files only, bounded in size.

A path given to the package (a data set's index, a clip, an importer's input, a YAML file) may
name a directory, a FIFO that never ends (reading it would hang), a device such as ``/dev/zero``
(reading it would fill the memory) or a file far larger than what it claims to be.
:func:`regular_file` refuses what is not a regular file before anything opens it,
:func:`open_bounded` opens one of at most a cap for streaming, and :func:`read_bounded` reads
one whole, each with one line naming the file and the problem.

Robot descriptions, ROS parameter files and BVH skeleton mappings are all a few kilobytes of
YAML, and this module is the only one that parses YAML. :func:`read_yaml_file` reads such a file
bounded (:data:`MAX_YAML_BYTES`) and refuses, besides what :func:`read_bounded` refuses, text
that is not UTF-8 and YAML syntax errors (reported with the line). Aliases are refused too
(:func:`load_yaml_text`): none of these files needs them, and a few kilobytes of nested aliases
("billion laughs") expand to gigabytes.
"""

from __future__ import annotations

import os
import stat
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, BinaryIO

import yaml

from audio2pose_ros.errors import Audio2PoseError, ConfigurationError
from audio2pose_ros.resources import share_path

__all__ = [
    "MAX_YAML_BYTES",
    "load_yaml_text",
    "open_bounded",
    "packaged_mapping",
    "read_bounded",
    "read_yaml_file",
    "regular_file",
]

MAX_YAML_BYTES = 1 << 20  # 1 MiB: the packaged YAML files are 1 to 10 KB


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
    """The bytes of a regular file of at most ``max_bytes`` (:func:`open_bounded`).

    Raises:
        Audio2PoseError: ``error`` for what :func:`open_bounded` refuses, or a file that
            cannot be read (or grew beyond ``max_bytes`` while it was read).
    """
    with open_bounded(path, what, error, max_bytes) as stream:
        try:
            size = os.fstat(stream.fileno()).st_size
            raw = stream.read(min(size, max_bytes) + 1)  # no buffer of max_bytes reserved
            if len(raw) > size:
                raw += stream.read(max_bytes + 1 - len(raw))
        except OSError as exc:
            raise error(f"{path}: cannot read ({exc.strerror or exc})") from None
    if len(raw) > max_bytes:
        raise error(f"{path}: larger than {max_bytes} bytes, not a {what} file")
    return raw


@contextmanager
def open_bounded(
    path: str | Path, what: str, error: type[Audio2PoseError], max_bytes: int
) -> Iterator[BinaryIO]:
    """``path`` opened for reading, once it is known to be a regular file of at most ``max_bytes``.

    :func:`regular_file` refuses a FIFO or a device before it is opened
    (reading one would hang or never end); the type and size are checked again on the opened
    file, so the file that is read is the one that was checked. Nothing is read ahead: the
    caller streams the file, or reads it whole, and no buffer of ``max_bytes`` is reserved.

    Raises:
        Audio2PoseError: ``error`` for a missing path, a directory, a special file, a file
            larger than ``max_bytes`` or one that cannot be opened.
    """
    file = regular_file(path, what, error)
    try:
        stream = file.open("rb")
    except OSError as exc:
        raise error(f"{file}: cannot read ({exc.strerror or exc})") from None
    with stream:
        status = os.fstat(stream.fileno())
        if not stat.S_ISREG(status.st_mode):
            raise error(f"{file}: not a regular file, expected a {what} file")
        if status.st_size > max_bytes:
            raise error(f"{file}: larger than {max_bytes} bytes, not a {what} file")
        yield stream


# --- YAML ------------------------------------------------------------------------------------


class _NoAliasLoader(yaml.SafeLoader):
    """yaml's safe loader, refusing aliases (``*name``) before they are expanded."""

    def compose_node(self, parent: yaml.Node | None, index: int) -> yaml.Node | None:
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()  # type: ignore[no-untyped-call]
            raise yaml.composer.ComposerError(
                None, None, "aliases (*name) are not accepted", event.start_mark
            )
        return super().compose_node(parent, index)


def load_yaml_text(text: str) -> object:
    """``yaml.safe_load`` without aliases (see the module text).

    Raises:
        yaml.YAMLError: invalid YAML, or an alias.
    """
    return yaml.load(text, Loader=_NoAliasLoader)


def read_yaml_file(
    path: str | Path,
    what: str,
    error: type[Audio2PoseError],
    max_bytes: int = MAX_YAML_BYTES,
) -> object:
    """Parse a small YAML file with ``yaml.safe_load``.

    Args:
        path: the file.
        what: what the file is, for messages (e.g. ``"robot description"``).
        error: the error class to raise (it names the file and the problem in one line).
        max_bytes: larger files are refused before they are parsed.

    Returns:
        The parsed document (None for an empty file).

    Raises:
        Audio2PoseError: ``error`` for a missing, special, oversized, non-UTF-8 or invalid file.
    """
    file = Path(path)
    raw = read_bounded(file, what, error, max_bytes)
    try:
        return load_yaml_text(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise error(f"{file}: not UTF-8 text, not a {what} file") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or type(exc).__name__
        raise error(f"{file}: not valid YAML{where} ({problem})") from None


def packaged_mapping(*parts: str) -> dict[str, Any]:
    """A YAML mapping the package ships (``share_path(*parts)``), read as any YAML file is.

    Raises:
        ConfigurationError: the file is missing, unreadable or not a mapping (a broken install).
    """
    path = share_path(*parts)
    data = read_yaml_file(path, "packaged YAML", ConfigurationError)
    if not isinstance(data, dict):
        raise ConfigurationError(f"{path}: expected a mapping")
    return data

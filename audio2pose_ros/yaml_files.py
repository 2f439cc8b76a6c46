"""Small YAML files read as untrusted input: bounded size, regular files, one-line errors.

Robot descriptions, ROS parameter files and BVH skeleton mappings are all a few kilobytes of
YAML. :func:`read_yaml_file` refuses what is not such a file before parsing it: a missing path,
a directory, a device or FIFO (reading ``/dev/zero`` would never end), a file above the size
cap, text that is not UTF-8, and YAML syntax errors (reported with the line). Aliases are
refused too (:func:`load_yaml_text`): none of these files needs them, and a few kilobytes of
nested aliases ("billion laughs") expand to gigabytes.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from audio2pose_ros.errors import Audio2PoseError, ConfigurationError
from audio2pose_ros.files import read_bounded
from audio2pose_ros.resources import share_path

__all__ = ["MAX_YAML_BYTES", "load_yaml_text", "packaged_mapping", "read_yaml_file"]

MAX_YAML_BYTES = 1 << 20  # 1 MiB: the packaged YAML files are 1 to 10 KB


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

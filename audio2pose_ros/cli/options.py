"""Command-line option types and path checks shared by every ``audio2pose`` verb.

Numbers are checked by argparse ``type=`` functions: a value that is not a number, is NaN or
infinite, or lies outside the option's range ends the command with one line naming the option,
the value and the allowed range, and exit status 2 (see :class:`OneLineParser`). Paths are
checked where the command uses them:

- an input must exist and be a regular file (or a directory where one is meant); otherwise an
  :class:`~audio2pose_ros.errors.InputError` names it (exit status 1). Special files such as
  ``/dev/zero`` are refused, so reading an input never runs without end;
- an output must be creatable: its folder exists and it is not a directory (or, for a new
  folder, does not exist yet); otherwise a :class:`~audio2pose_ros.errors.UsageError` (exit 2).
"""

from __future__ import annotations

import argparse
import math
import os
import stat
import sys
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import NoReturn, TypeAlias, TypeVar

from audio2pose_ros.errors import InputError, UsageError

NumberT = TypeVar("NumberT", int, float)
#: The sub-command table each ``*_commands.register`` adds its verbs to.
Verbs: TypeAlias = "argparse._SubParsersAction[OneLineParser]"

__all__ = [
    "MAX_SEED",
    "NamedPath",
    "OneLineParser",
    "add_force",
    "add_voice_out_option",
    "bag_inputs",
    "bounded_float",
    "bounded_int",
    "check_apart",
    "input_bag",
    "input_dir",
    "input_file",
    "new_dir",
    "output_file",
]

MAX_SEED = 2**32 - 1  # numpy and torch both accept seeds in [0, 2**32)


class OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line on stderr (exit status 2), usage in --help."""

    def error(self, message: str) -> NoReturn:
        """Print ``<prog>: error: <message> (see <prog> --help)`` and exit with status 2."""
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _number(kind: Callable[[str], NumberT], text: str) -> NumberT:
    try:
        return kind(text)
    except ValueError:
        what = "an integer" if kind is int else "a number"
        raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None


def bounded_float(low: float, high: float, low_inclusive: bool = True) -> Callable[[str], float]:
    """An argparse type: a finite float in [low, high] (or (low, high] when not inclusive)."""

    def parse(text: str) -> float:
        value = _number(float, text)
        inside = (value >= low if low_inclusive else value > low) and value <= high
        if not math.isfinite(value) or not inside:
            bracket = "[" if low_inclusive else "("
            raise argparse.ArgumentTypeError(
                f"{text!r} is not a finite number in {bracket}{low:g}, {high:g}]"
            )
        return value

    parse.__name__ = "number"
    return parse


def bounded_int(low: int, high: int) -> Callable[[str], int]:
    """An argparse type: an integer in [low, high]."""

    def parse(text: str) -> int:
        value = _number(int, text)
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer in [{low}, {high}]")
        return value

    parse.__name__ = "integer"
    return parse


def _stat(path: Path, what: str) -> os.stat_result:
    try:
        return path.stat()
    except FileNotFoundError:
        raise InputError(f"{path}: {what} not found") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot access {what} ({exc.strerror or exc})") from None


def input_file(name: str | os.PathLike[str], what: str = "input file") -> Path:
    """``name`` as a Path after checking it is an existing, readable regular file.

    Raises:
        InputError: it does not exist, is a directory or a special file, or is not readable.
    """
    path = Path(name)
    mode = _stat(path, what).st_mode
    if stat.S_ISDIR(mode):
        raise InputError(f"{path}: is a directory, expected a {what}")
    if not stat.S_ISREG(mode):
        raise InputError(f"{path}: not a regular file, expected a {what}")
    if not os.access(path, os.R_OK):
        raise InputError(f"{path}: {what} is not readable (permission denied)")
    return path


def input_dir(name: str | os.PathLike[str], what: str = "input folder") -> Path:
    """``name`` as a Path after checking it is an existing, readable directory.

    Raises:
        InputError: it does not exist, is not a directory or is not readable.
    """
    path = Path(name)
    if not stat.S_ISDIR(_stat(path, what).st_mode):
        raise InputError(f"{path}: not a directory, expected a {what}")
    if not os.access(path, os.R_OK | os.X_OK):
        raise InputError(f"{path}: {what} is not readable (permission denied)")
    return path


def input_bag(name: str | os.PathLike[str]) -> Path:
    """A rosbag2 input: a bag folder, or one storage file (``.mcap`` / ``.db3``).

    Raises:
        InputError: it does not exist or is neither a readable folder nor a regular file.
    """
    path = Path(name)
    return input_dir(path, "bag folder") if path.is_dir() else input_file(path, "bag")


def _writable_parent(path: Path, option: str) -> None:
    parent = path.parent if str(path.parent) else Path()
    if not parent.is_dir():
        raise UsageError(f"{option} {path}: folder {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise UsageError(f"{option} {path}: folder {parent} is not writable")


def _same_file(a: Path, b: Path) -> bool:
    """Whether two existing paths are one file (symlinks followed, hard links compared)."""
    try:
        first, second = a.stat(), b.stat()
    except OSError:
        return False
    return (first.st_dev, first.st_ino) == (second.st_dev, second.st_ino)


def output_file(
    name: str | os.PathLike[str],
    option: str,
    inputs: Iterable[str | os.PathLike[str] | None] = (),
    force: bool = False,
) -> Path:
    """``name`` as a Path after checking a file may be written there.

    Args:
        name: the file to write.
        option: the option that named it (for the message).
        inputs: the files the command reads: the output is never one of them, whatever the
            path it is given by (a symlink, a hard link, ``./``).
        force: an existing file may be replaced (``--force``); without it, it is refused.

    Raises:
        UsageError: its folder is missing or not writable, the path is a directory, it is one
            of the inputs, or it exists and ``force`` is not given.
    """
    path = Path(name)
    if path.is_dir():
        raise UsageError(f"{option} {path}: is a directory, expected a file name")
    _writable_parent(path, option)
    for source in inputs:
        if source is not None and _same_file(path, Path(source)):
            raise UsageError(f"{option} {path}: is the input {source}; give another output file")
    if not force and (path.exists() or path.is_symlink()):
        raise UsageError(f"{option} {path}: exists already; give --force to replace it")
    return path


def add_force(parser: argparse.ArgumentParser) -> None:
    """``--force``: let the command replace an existing output file (never one of its inputs)."""
    parser.add_argument("--force", action="store_true", help="replace the output file if it exists")


def new_dir(name: str | os.PathLike[str], option: str, parents: bool = False) -> Path:
    """``name`` as a Path after checking it does not exist yet and can be created.

    Args:
        name: the folder to create later.
        option: the option that named it (for the message).
        parents: when True the folder's own parents may be missing (they are created later).

    Raises:
        UsageError: it exists already, or its folder is missing or not writable.
    """
    path = Path(name)
    if path.exists():
        raise UsageError(f"{option} {path}: exists already; give a new folder")
    if not parents:
        _writable_parent(path, option)
    return path


BAG_FILE_SUFFIXES = (".mcap", ".db3", ".yaml")  # what a rosbag2 folder holds (metadata.yaml)


def _is_bag_dir(path: Path) -> bool:
    """A real folder with ``metadata.yaml`` and nothing but bag files in it."""
    if not path.is_dir() or path.is_symlink():
        return False
    return (path / "metadata.yaml").is_file() and all(
        entry.is_file() and not entry.is_symlink() and entry.suffix in BAG_FILE_SUFFIXES
        for entry in path.iterdir()
    )


def bag_dir(name: str | os.PathLike[str], option: str, force: bool) -> Path:
    """``name`` as the folder of a new rosbag2 bag: missing, or an old bag and ``force`` given.

    Only a folder that is a bag may be replaced (:func:`remove_bag_dir`, when the new one is
    written); anything else stays refused, ``force`` or not, so a mistyped path cannot cost the
    user a folder.

    Raises:
        UsageError: it exists and is not a bag, or ``force`` is not given, or its folder is
            missing or not writable.
    """
    path = Path(name)
    if not (path.exists() or path.is_symlink()):
        return new_dir(path, option)
    if not force:
        raise UsageError(f"{option} {path}: exists already; give --force to replace it")
    if not _is_bag_dir(path):
        raise UsageError(f"{option} {path}: exists and is not a rosbag2 bag; give a new folder")
    return path


def remove_bag_dir(path: Path) -> None:
    """Remove an old bag accepted by :func:`bag_dir` (its files, then the folder)."""
    if _is_bag_dir(path):
        for entry in path.iterdir():
            entry.unlink()
        path.rmdir()


def one_line(message: str) -> str:
    """``message`` with its lines joined by `` | `` (a report is one line on stderr)."""
    return " | ".join(part.strip() for part in message.splitlines() if part.strip())


def report(prog: str, message: str) -> None:
    """Print ``<prog>: <message>`` as one line on stderr."""
    print(f"{prog}: {one_line(message)}", file=sys.stderr, flush=True)


#: A path a command reads or writes, for :func:`check_apart`: its description (naming the
#: option and the path, as the user gave them) and the path (``None``: not given).
NamedPath: TypeAlias = tuple[str, str | os.PathLike[str] | None]


def _lineage(path: Path) -> list[Path]:
    """``path`` with symlinks resolved (as far as it exists), then each folder above it."""
    real = Path(os.path.realpath(path))
    return [real, *real.parents]


def _same(a: Path, b: Path) -> bool:
    """One path, or one existing file or folder by two paths (a bind mount, a hard link)."""
    if a == b:
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def bag_inputs(label: str, name: str | os.PathLike[str] | None) -> list[NamedPath]:
    """A bag input for :func:`check_apart`, its folder included.

    ``label`` describes it ("the input --bag"). A storage file of a bag folder (one with
    ``metadata.yaml``) brings that folder, which an output must not touch either.
    """
    if name is None:
        return []
    path = Path(name)
    named: list[NamedPath] = [(f"{label} {path}", path)]
    if not path.is_dir() and (path.parent / "metadata.yaml").is_file():
        named.append((f"the folder {path.parent} of {label} {path}", path.parent))
    return named


def check_apart(
    output: str | os.PathLike[str], option: str, others: Iterable[NamedPath], instead: str
) -> None:
    """Refuse an output that is, contains or is inside one of ``others``.

    ``others`` are what the command reads, or its other outputs; call this before anything is
    written or deleted. Paths are compared with symlinks resolved and, where they exist, as
    files (a bind mount or a hard link is the same file): an output reached through a link is
    still caught.

    Args:
        output: the file or folder the command will write (it may not exist yet).
        option: the option that named it, for the message.
        others: (description, path) of each path to keep apart; ``None`` paths are skipped.
        instead: what to give instead, for the message ("another folder").

    Raises:
        UsageError: one line, naming both paths and how they overlap.
    """
    out = _lineage(Path(output))
    for description, name in others:
        if name is None:
            continue
        other = _lineage(Path(name))
        if _same(out[0], other[0]):
            relation = "is"
        elif any(_same(folder, out[0]) for folder in other[1:]):
            relation = "contains"
        elif any(_same(folder, other[0]) for folder in out[1:]):
            relation = "is inside"
        else:
            continue
        raise UsageError(f"{option} {output}: {relation} {description}; give {instead}")


def check_robot_options(args: argparse.Namespace) -> None:
    """``--sim`` and ``--no-robot`` (``run``, ``console``) cannot be given together.

    Raises:
        UsageError: both were given.
    """
    if args.sim and args.no_robot:
        raise UsageError("--sim and --no-robot: the simulated Pepper publishes joint_states")


def add_voice_out_option(parser: argparse.ArgumentParser) -> None:
    """``--voice-out``: the operator's voice out of the robot, in step with the motion."""
    parser.add_argument(
        "--voice-out",
        metavar="naoqi:tcp://HOST:PORT|naoqi|topic",
        help="play the operator's voice at the robot, held back by the measured motion latency: "
        "naoqi:tcp://HOST:9559 (Pepper's loudspeakers through NAOqi), naoqi (with --sim: the "
        "simulated Pepper's), or topic (audio_out, for audio_common's audio_play)",
    )

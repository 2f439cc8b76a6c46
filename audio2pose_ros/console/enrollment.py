"""The console's "learn my style": a recording from the page becomes a personal style, here.

The operator's page asks for consent, records camera and microphone for up to
:data:`MAX_RECORDING_S` and uploads the recording to the console; nothing leaves the machine.
:class:`Enrollments` is the console's side of it, free of ROS and of the web server:

1. **A ticket.** An identified operator who may act on the robot's settings (the floor is free or
   theirs) asks for one (:meth:`Enrollments.ticket`): a random, single-use name for one upload,
   valid for :data:`TICKET_TTL_S`, bound to that operator's connection. One enrollment runs at a
   time (the machine has few cores, and the robot one style): a ticket is refused while another
   recording is being uploaded or learned.
2. **The upload** (:meth:`Enrollments.receive`): the recording is streamed into a private folder
   (mode 0700) under the console's work folder, at most :data:`MAX_RECORDING_BYTES` within
   :data:`UPLOAD_TIMEOUT_S`; a larger, slower or empty upload, or one with an unknown, used or
   expired ticket, is refused and nothing of it is kept. So is, before it is accepted, a
   recording that learning would refuse or could not read bounded (:func:`check_recording`):
   longer than :data:`MAX_UPLOAD_S`, without audio or video, or with frames too large.
3. **Learning** (:meth:`Enrollments.run`): the recording goes through the same importer and
   style fit as ``audio2pose enroll`` (:func:`audio2pose_ros.style.personal.enroll`), in a child
   process (:mod:`audio2pose_ros.console.enroll_worker`; the console itself never loads the
   model, MediaPipe or torch) at low priority, with its data bounded to
   :data:`ENROLL_MEMORY_BYTES`, at most :data:`ENROLL_TIMEOUT_S`. Its progress lines are the
   status every page sees; when it fails, its reason (or how it ended) is.
4. **The result**: the personal model folder (``style.yaml``, ``ENROLLMENT.md`` and, when
   enrolment fitted the arms' own noise, ``model.safetensors``), the style settings fitted to
   that model, and per part what cross-validation decided (:class:`Result`): the gain expected
   on the person's other speech with its spread, or that the default was kept and why. The
   console runs it without a restart: the inference node's ``model_path`` is set to the folder
   (the node blends its checkpoint in) and the filter's live style parameters to the settings.
   The operator can go back to the model and style the graph started with at any time.
5. **The recording** is deleted when learning ends, whatever the outcome, unless the operator
   asked to keep it: it is then moved into the personal model folder, beside the style learned
   from it.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import os
import secrets
import shutil
import sys
import time
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from audio2pose_ros.errors import InputError

__all__ = [
    "ENROLL_MEMORY_BYTES",
    "ENROLL_TIMEOUT_S",
    "MAX_RECORDING_BYTES",
    "MAX_RECORDING_S",
    "MAX_UPLOAD_S",
    "TICKET_TTL_S",
    "UPLOAD_TIMEOUT_S",
    "EnrollmentError",
    "Enrollments",
    "Result",
    "Ticket",
    "check_recording",
    "default_work_dir",
    "personal_model_note",
]

MAX_RECORDING_S = 60.0  # the page stops recording after this long
MAX_RECORDING_BYTES = 64 * 1024 * 1024  # 60 s of camera and microphone at about 8 Mbit/s
MAX_UPLOAD_S = MAX_RECORDING_S + 5.0  # a longer recording did not come from the page: refused
TICKET_TTL_S = 120.0  # an upload must start this soon after its ticket (recording included)
UPLOAD_TIMEOUT_S = 120.0  # an upload that takes longer is dropped (a trickle holds no slot)
ENROLL_TIMEOUT_S = 300.0  # the child process is killed after this long
# the child's data (heap and anonymous mappings, RLIMIT_DATA): a 60 s enrolment takes about
# 0.8 GiB of it (0.6 GiB resident) with torch and MediaPipe loaded
ENROLL_MEMORY_BYTES = 3 * 2**29  # 1.5 GiB
SETTINGS_PREFIX = "STYLE_SETTINGS "  # the worker's last line: the resolved settings as JSON
MODEL_PREFIX = "PERSONAL_MODEL "  # the worker's line before: the personal model as JSON
MAX_VERDICT_CHARS = 400  # a verdict's sentence shown to the pages is cut to this length
FAILED_PREFIX = "ENROLL_FAILED "  # the worker's last line when it fails: the reason
MAX_PROGRESS_CHARS = 200  # a progress line shown to the pages is cut to this length
RECORDING_NAME = "recording.webm"
CONTENT_TYPES = ("video/webm", "video/mp4", "video/x-matroska")


class EnrollmentError(InputError):
    """An enrollment request or upload is refused (the message says why)."""


def default_work_dir() -> Path:
    """``$ROS_HOME/audio2pose_ros/console/`` (ROS_HOME defaults to ``~/.ros``)."""
    ros_home = os.environ.get("ROS_HOME") or str(Path.home() / ".ros")
    return Path(ros_home) / "audio2pose_ros" / "console"


@dataclass
class Ticket:
    """One upload's permission: whose connection asked, and whether to keep the recording."""

    session: int
    owner: str
    keep: bool
    expires_s: float


@dataclass
class Result:
    """A finished enrollment.

    Attributes:
        folder: the personal model folder.
        settings: the style alone against the packaged model (a graph that keeps its model).
        kept_recording: where the recording was kept, or None (deleted).
        model_settings: the style fitted to the folder's model (what runs with it).
        verdicts: per part, ``part``, ``learned``, ``gain``, ``spread``, ``reason`` and
            ``line`` (:func:`~audio2pose_ros.console.enroll_worker.model_line`).
    """

    folder: Path
    settings: dict[str, float]
    kept_recording: Path | None
    model_settings: dict[str, float] = field(default_factory=dict)
    verdicts: list[dict[str, Any]] = field(default_factory=list)


@dataclass
class _State:
    state: str = "idle"  # idle, waiting, uploading, learning, ready, failed
    owner: str = ""
    message: str = ""
    started_s: float = 0.0
    progress: list[str] = field(default_factory=list)


class Enrollments:
    """Tickets, uploads and learning runs of the console (see the module docstring).

    Args:
        work_dir: where recordings and personal models are kept (created, mode 0700).
        command: the child process's command without its two arguments (recording, folder);
            by default this interpreter running :mod:`audio2pose_ros.console.enroll_worker`.
        clock: monotonic seconds (tests pass their own).
    """

    def __init__(
        self,
        work_dir: Path,
        command: list[str] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.work_dir = work_dir
        self.command = command or [sys.executable, "-m", "audio2pose_ros.console.enroll_worker"]
        self.clock = clock
        self._tickets: dict[str, Ticket] = {}
        self._state = _State()
        self.result: Result | None = None
        self.completed = 0
        self.failed = 0

    # --- status ---------------------------------------------------------------------------------

    def status(self) -> dict[str, Any]:
        """What every page is shown: state, who started it, the last progress line."""
        return {
            "state": self._state.state,
            "owner": self._state.owner,
            "message": self._state.message,
            "personal": str(self.result.folder.name) if self.result else "",
            "verdicts": self.result.verdicts if self.result else [],
        }

    def _set(self, state: str, message: str, owner: str | None = None) -> None:
        self._state.state = state
        self._state.message = " ".join(message.split())[:MAX_PROGRESS_CHARS]
        if owner is not None:
            self._state.owner = owner

    @property
    def busy(self) -> bool:
        """Whether a recording is awaited, being uploaded or being learned."""
        self._expire()
        return self._state.state in ("waiting", "uploading", "learning")

    # --- tickets --------------------------------------------------------------------------------

    def _expire(self) -> None:
        now = self.clock()
        for key in [k for k, t in self._tickets.items() if t.expires_s <= now]:
            del self._tickets[key]
        if self._state.state == "waiting" and not self._tickets:
            self._set("idle", "the recording did not arrive in time")

    def ticket(self, session: int, owner: str, keep: bool) -> str:
        """A single-use upload ticket for ``session``.

        Raises:
            EnrollmentError: another enrollment is under way.
        """
        if self.busy:
            raise EnrollmentError(
                f"{self._state.owner or 'another operator'} is already teaching a style: "
                "wait until it is done"
            )
        key = secrets.token_urlsafe(24)
        self._tickets = {key: Ticket(session, owner, keep, self.clock() + TICKET_TTL_S)}
        self._set("waiting", f"recording {owner}'s style", owner)
        return key

    def forget_session(self, session: int) -> None:
        """A page left: its ticket, if any, is void."""
        for key in [k for k, t in self._tickets.items() if t.session == session]:
            del self._tickets[key]
        if self._state.state == "waiting" and not self._tickets:
            self._set("idle", "the operator left before uploading a recording")

    def _take(self, key: str) -> Ticket:
        self._expire()
        for known, ticket in list(self._tickets.items()):
            if secrets.compare_digest(known.encode(), key.encode("utf-8", "replace")):
                del self._tickets[known]
                return ticket
        raise EnrollmentError("unknown, used or expired upload ticket")

    # --- upload ---------------------------------------------------------------------------------

    async def receive(
        self, key: str, content_type: str, chunks: AsyncIterator[bytes]
    ) -> tuple[Ticket, Path]:
        """Store one upload under its ticket; returns the ticket and the recording's path.

        Raises:
            EnrollmentError: bad ticket or type, empty or larger than :data:`MAX_RECORDING_BYTES`,
                or refused by :func:`check_recording` (nothing is kept then).
        """
        ticket = self._take(key)
        kind = content_type.split(";", 1)[0].strip().lower()
        if kind not in CONTENT_TYPES:
            self._set("idle", "refused a recording that is not a video")
            raise EnrollmentError(f"a recording must be one of {list(CONTENT_TYPES)}")
        self._set("uploading", f"receiving {ticket.owner}'s recording", ticket.owner)
        self.work_dir.mkdir(parents=True, exist_ok=True, mode=0o700)
        job = Path(
            await asyncio.to_thread(
                _private_dir, self.work_dir, time.strftime("style-%Y%m%d-%H%M%S")
            )
        )
        path = job / RECORDING_NAME

        async def store() -> int:
            size = 0
            with open(path, "xb") as out:
                async for chunk in chunks:
                    size += len(chunk)
                    if size > MAX_RECORDING_BYTES:
                        raise EnrollmentError(
                            f"the recording is over {MAX_RECORDING_BYTES // 2**20} MB"
                        )
                    out.write(chunk)
            return size

        try:
            try:
                size = await asyncio.wait_for(store(), UPLOAD_TIMEOUT_S)
            except asyncio.TimeoutError:
                raise EnrollmentError(
                    f"the recording did not arrive within {UPLOAD_TIMEOUT_S:g} s"
                ) from None
            if size == 0:
                raise EnrollmentError("the recording is empty")
            await asyncio.to_thread(check_recording, path)
        except BaseException:
            shutil.rmtree(job, ignore_errors=True)
            self._set("idle", "the recording was refused or did not arrive whole")
            raise
        return ticket, path

    # --- learning -------------------------------------------------------------------------------

    async def run(self, ticket: Ticket, recording: Path) -> Result:
        """Learn the style of ``recording`` in a child process; delete it unless it is kept.

        Raises:
            EnrollmentError: the child failed (its last line says why) or took too long.
        """
        job = recording.parent
        folder = job / "style"
        self._set("learning", "learning the style (this takes up to two minutes)", ticket.owner)
        try:
            settings, model = await self._child(recording, folder)
        except BaseException as exc:
            self.failed += 1
            shutil.rmtree(job, ignore_errors=True)
            self._set("failed", f"could not learn the style: {exc}")
            raise
        kept: Path | None = None
        if ticket.keep:
            kept = folder / RECORDING_NAME
            recording.replace(kept)
        else:
            recording.unlink(missing_ok=True)
        (job / "learning.log").unlink(missing_ok=True)
        self.completed += 1
        self.result = Result(folder, settings, kept, *model)
        note = personal_model_note(folder)
        self._set("ready", f"learned {ticket.owner}'s style{note}", ticket.owner)
        return self.result

    async def _child(
        self, recording: Path, folder: Path
    ) -> tuple[dict[str, float], tuple[dict[str, float], list[dict[str, Any]]]]:
        # the libraries' own chatter (MediaPipe, protobuf) goes to a log beside the recording,
        # deleted with it; the pages see the worker's progress lines only
        with open(recording.parent / "learning.log", "wb") as log:
            process = await asyncio.create_subprocess_exec(
                *self.command,
                str(recording),
                str(folder),
                stdin=asyncio.subprocess.DEVNULL,
                stdout=asyncio.subprocess.PIPE,
                stderr=log,
            )
        found: list[dict[str, float]] = []
        models: list[tuple[dict[str, float], list[dict[str, Any]]]] = []
        failed: list[str] = []

        async def read() -> None:
            assert process.stdout is not None
            async for raw in process.stdout:
                line = raw.decode("utf-8", "replace").strip()
                if line.startswith(SETTINGS_PREFIX):
                    found.append(_settings(line.removeprefix(SETTINGS_PREFIX)))
                elif line.startswith(MODEL_PREFIX):
                    models.append(_model(line.removeprefix(MODEL_PREFIX)))
                elif line.startswith(FAILED_PREFIX):
                    failed.append(line.removeprefix(FAILED_PREFIX))
                elif line:
                    self._set("learning", line)
            await process.wait()

        try:
            await asyncio.wait_for(read(), ENROLL_TIMEOUT_S)
        except asyncio.TimeoutError:
            raise EnrollmentError(f"learning took over {ENROLL_TIMEOUT_S:g} s") from None
        finally:
            if process.returncode is None:
                with contextlib.suppress(ProcessLookupError):
                    process.kill()
                await process.wait()
        if failed:
            raise EnrollmentError(failed[-1])
        if process.returncode is not None and process.returncode < 0:
            raise EnrollmentError(
                f"the learning process was stopped by signal {-process.returncode} (a crash, "
                f"or its memory bound of {ENROLL_MEMORY_BYTES / 2**30:g} GiB reached)"
            )
        if process.returncode != 0 or not found or not models:
            raise EnrollmentError(
                f"the learning process ended (exit code {process.returncode}) without a result"
            )
        return found[-1], models[-1]


def check_recording(path: Path) -> float:
    """The length of an uploaded recording (s), after checking that learning can read it bounded.

    Its audio is decoded up to :data:`MAX_UPLOAD_S` and a second more (a container's duration
    is a claim, and a browser's recording declares none), and its video stream's header is
    read (:func:`~audio2pose_ros.data.importers.media.check_video`); nothing is kept.

    Raises:
        EnrollmentError: longer than :data:`MAX_UPLOAD_S`, no audio or video, frames too large,
            or not readable as media; the message does not name the server's path.
    """
    from audio2pose_ros.data.importers.media import check_video, probe_media, read_audio
    from audio2pose_ros.timebase import SAMPLE_RATE_HZ

    try:
        check_video(path, probe_media(path))
        seconds = read_audio(path, MAX_UPLOAD_S + 1.0).size / SAMPLE_RATE_HZ
    except InputError as exc:
        reason = str(exc).removeprefix(f"{path}: ")
        raise EnrollmentError(f"the recording cannot be learned from: {reason}") from None
    if seconds > MAX_UPLOAD_S:
        raise EnrollmentError(
            f"the recording is longer than {MAX_UPLOAD_S:g} s; learning a style takes a "
            f"recording of at most {MAX_RECORDING_S:g} s"
        )
    return seconds


def personal_model_note(folder: Path) -> str:
    """What the personal model runs beyond the style ('' when nothing): the arms' own noise.

    When enrolment fitted the arms' own sampling noise, the folder holds its checkpoint, which
    the console has the inference node blend in (and ``audio2pose run --model FOLDER`` runs).
    """
    from audio2pose_ros.checkpoints.switch import CHECKPOINT_FILE

    if not (folder / CHECKPOINT_FILE).is_file():
        return ""
    return "; with its arms' own noise (a model of its own)"


def _private_dir(parent: Path, stem: str) -> str:
    """A new folder under ``parent`` only this user can read (never an existing one)."""
    for n in range(1000):
        candidate = parent / (stem if n == 0 else f"{stem}-{n}")
        try:
            candidate.mkdir(mode=0o700)
        except FileExistsError:
            continue
        return str(candidate)
    raise EnrollmentError(f"{parent}: no free folder name for a recording")


def _model(text: str) -> tuple[dict[str, float], list[dict[str, Any]]]:
    """The worker's personal model line: its settings and its verdicts, checked."""
    try:
        values = json.loads(text)
    except ValueError:
        raise EnrollmentError("the learning process gave an unreadable personal model") from None
    verdicts = values.get("verdicts") if isinstance(values, dict) else None
    if not isinstance(verdicts, list):
        raise EnrollmentError("the learning process gave a personal model without verdicts")
    checked = []
    for v in verdicts:
        if not isinstance(v, dict) or not isinstance(v.get("line"), str):
            raise EnrollmentError("the learning process gave a verdict that cannot be read")
        numbers = [0.0, 0.0]  # a part kept for lack of data may have no finite spread
        gain, spread = v.get("gain"), v.get("spread")
        pair = [x for x in (gain, spread) if isinstance(x, int | float) and math.isfinite(x)]
        if len(pair) == 2:
            numbers = [float(x) for x in pair]
        checked.append(
            {
                "part": str(v.get("part", ""))[:16],
                "learned": bool(v.get("learned")),
                "gain": float(numbers[0]),
                "spread": float(numbers[1]),
                "reason": str(v.get("reason", ""))[:MAX_VERDICT_CHARS],
                "line": v["line"][:MAX_VERDICT_CHARS],
            }
        )
    return _settings(json.dumps(values.get("settings"))), checked


def _settings(text: str) -> dict[str, float]:
    """The worker's settings line: a JSON object of finite numbers."""
    try:
        values = json.loads(text)
    except ValueError:
        raise EnrollmentError("the learning process gave unreadable settings") from None
    if not isinstance(values, dict) or not all(
        isinstance(k, str) and isinstance(v, int | float) and math.isfinite(v)
        for k, v in values.items()
    ):
        raise EnrollmentError("the learning process gave settings that are not finite numbers")
    return {k: float(v) for k, v in values.items()}

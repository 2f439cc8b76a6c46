"""The console's "learn my style" endpoints: tickets, the upload, and the style the graph uses.

:class:`~audio2pose_ros.console.enrollment.Enrollments` does the work (tickets, the bounded
upload, learning in a child process); this module is its web side, which
:class:`~audio2pose_ros.console.server.ConsoleServer` wires in:

- the page's ``enroll`` message asks for a ticket (:meth:`LearnMyStyle.on_control`, answered
  ``enroll_ticket``); its ``style`` message chooses the learned style, a named preset (its
  settings for the packaged model, as the preset file keeps them:
  :func:`~audio2pose_ros.style.personal.packaged_preset`) or the graph's own style, and its
  ``style_set`` message sets single style parameters (the page's sliders);
- ``POST /enroll/{ticket}`` (:meth:`LearnMyStyle.upload`) streams the recording under that
  ticket, after the same Host and Origin checks as the WebSocket (403); a request announcing
  more than :data:`~audio2pose_ros.console.enrollment.MAX_RECORDING_BYTES` is refused (413)
  before it is read, and any refused upload (400) is counted in the console's summary of
  refusals, not logged one line each (a stream of guessed tickets is one line per summary);
- the personal model is applied to the running graph when learning ends, if its operator is
  still connected and may act on the robot's settings (the floor is free or theirs) and the
  stop is released: the inference node runs the folder (its ``model_path``, blended in without a
  restart; the checkpoint of the arms' own noise when enrolment fitted one) and the filter the
  style fitted to it. "Use my style" applies it again; "Back to the default" (``style`` with
  ``default``) and a preset (whose settings are for the packaged model) give the inference node
  back the model it started with, blended as well. The sliders change the style alone.
- every page's status carries, per part, what cross-validation decided (``enrollment``'s
  ``verdicts``): the gain expected on the person's other speech with its spread, or that the
  default was kept and why.
"""

from __future__ import annotations

import asyncio
import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

from aiohttp import web

from audio2pose_ros.console.access import Access, client_key, request_problem
from audio2pose_ros.console.enrollment import (
    MAX_RECORDING_BYTES,
    EnrollmentError,
    Enrollments,
    Result,
    Ticket,
    personal_model_note,
)
from audio2pose_ros.console.protocol import Control, ProtocolError, encode
from audio2pose_ros.motion.style import StyleSettings
from audio2pose_ros.parameters import specs_of
from audio2pose_ros.style.figures import StyleError, preset_names
from audio2pose_ros.style.personal import packaged_preset

__all__ = ["LearnMyStyle", "StyleBridge"]


class StyleBridge(Protocol):
    """What learning a style needs of the robot's side: the filter's style, the model run."""

    def set_style(self, settings: dict[str, float] | None) -> None:
        """Apply a learned style's settings to the graph (None: the style it started with)."""

    def set_model(self, folder: str | None, fallback: dict[str, float] | None = None) -> None:
        """Run a personal model folder on the inference node (None: the model it started with).

        ``fallback``: the style to apply instead if the node refuses the folder's model (the
        style alone, fitted to the model that keeps running).
        """


class LearnMyStyle:
    """Tickets, uploads and the style in use, for the console's pages.

    Args:
        enrollments: the enrollments (tickets, uploads, learning).
        access: the bind and token rules (the upload's Host and Origin checks).
        bridge: where a style is applied.
        log: ``log(level, message)`` with level ``info`` or ``warning``.
        refused: counts one refused upload under its reason, for the console's summary.
        may_apply: whether the operator of a session (by its id) is still connected and may
            act on the robot's settings now.
    """

    def __init__(
        self,
        enrollments: Enrollments,
        access: Access,
        bridge: StyleBridge,
        log: Callable[[str, str], None],
        refused: Callable[[str], None],
        may_apply: Callable[[int], bool],
    ) -> None:
        self.enrollments = enrollments
        self.access = access
        self.bridge = bridge
        self.log = log
        self.refused = refused
        self.may_apply = may_apply
        # "default" (the graph's own), "personal" (the learned one), a preset's name, or
        # "adjusted" (single parameters set from the page since)
        self.style_in_use = "default"
        self.presets = preset_names()
        # each live style parameter's range, from its declaration: the page's sliders
        self.ranges = {spec.name: [spec.minimum, spec.maximum] for spec in specs_of(StyleSettings)}
        self._learning: list[asyncio.Task[None]] = []

    def status(self) -> dict[str, Any]:
        """Progress, style in use, presets, style parameters' ranges: every page's status."""
        return {
            "enrollment": self.enrollments.status(),
            "style": self.style_in_use,
            "presets": self.presets,
            "style_ranges": self.ranges,
        }

    def stop(self) -> None:
        """Cancel learning still running (the console stops)."""
        for task in self._learning:
            task.cancel()

    async def upload(self, request: web.Request) -> web.Response:
        """One recording, streamed under a ticket a page asked for; learned in the background."""
        key = client_key(request.remote or "?")
        problem = request_problem(
            self.access, request.headers.get("Host"), request.headers.get("Origin")
        )
        if problem:
            self.refused(f"{key} (upload: {problem})")
            raise web.HTTPForbidden(text=problem)
        length = request.content_length
        if length is not None and length > MAX_RECORDING_BYTES:
            self.refused(f"{key} (upload too large)")
            raise web.HTTPRequestEntityTooLarge(
                max_size=MAX_RECORDING_BYTES, actual_size=length, text="recording too large"
            )
        try:
            ticket, recording = await self.enrollments.receive(
                request.match_info["ticket"],
                request.headers.get("Content-Type", ""),
                request.content.iter_chunked(1 << 16),
            )
        except EnrollmentError as exc:  # tallied: a stream of guesses is one line per summary
            self.refused(f"{key} (upload refused)")
            raise web.HTTPBadRequest(text=str(exc)) from None
        self.log("info", f"console: learning {ticket.owner!r}'s style from their recording")
        self._learning = [task for task in self._learning if not task.done()]
        self._learning.append(asyncio.create_task(self._learn(ticket, recording)))
        return web.json_response({"learning": True}, status=202)

    async def _learn(self, ticket: Ticket, recording: Path) -> None:
        """Learn; then apply the style if its operator may still act on the robot's settings."""
        try:
            result = await self.enrollments.run(ticket, recording)
        except Exception as exc:  # the boundary: the console carries on with the old style
            self.log("warning", f"console: learning {ticket.owner!r}'s style failed: {exc}")
            return
        kept = f", recording kept in {result.kept_recording}" if result.kept_recording else ""
        note = personal_model_note(result.folder)
        self.log("info", f"console: learned {ticket.owner!r}'s style: {result.folder}{kept}{note}")
        for verdict in result.verdicts:
            self.log("info", f"console: {verdict['line']}")
        if self.may_apply(ticket.session):
            self._use_personal(result)
            self.style_in_use = "personal"

    def _use_personal(self, result: Result) -> None:
        """The personal model: its style on the filter, its folder on the inference node.

        Should the node refuse the folder's model, the style alone (fitted to the packaged
        model) replaces the style fitted to the personal one.
        """
        self.bridge.set_style(result.model_settings or result.settings)
        self.bridge.set_model(str(result.folder), fallback=result.settings)

    def on_control(self, session_id: int, name: str, control: Control) -> str | None:
        """``enroll`` (a ticket), ``style`` (which style) and ``style_set`` (single parameters).

        Returns:
            The message to send back to the page (``enroll_ticket``), or None.

        Raises:
            ProtocolError: no ticket now (another enrollment runs), no learned style yet, or
                no usable preset of that name.
        """
        if control.type == "enroll":
            try:
                key = self.enrollments.ticket(session_id, name, control.fields["keep"])
            except EnrollmentError as exc:
                raise ProtocolError(str(exc)) from None
            return encode("enroll_ticket", ticket=key)
        if control.type == "style_set":
            self.bridge.set_style({k: float(v) for k, v in control.fields.items()})
            self.style_in_use = "adjusted"
            return None
        use = control.fields["use"]
        if use == "personal":
            result = self.enrollments.result
            if result is None:
                raise ProtocolError("no style has been learned yet: press Learn my style")
            self._use_personal(result)
        elif use == "default":
            self.bridge.set_model(None)
            self.bridge.set_style(None)
        else:
            try:  # every parameter: what the preset does not set goes back to the identity
                settings = dataclasses.asdict(packaged_preset(use))
            except StyleError as exc:
                raise ProtocolError(str(exc)) from None
            self.bridge.set_model(None)  # a preset's settings are for the packaged model
            self.bridge.set_style(settings)
        self.style_in_use = use
        return None

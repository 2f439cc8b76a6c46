"""What the connected operators may do to the robot: the floor, the stop and its owners.

:class:`Room` acts on the control messages of identified operators (after the server's checks
of the connection, the token and the message, :mod:`~audio2pose_ros.console.protocol`):

- **The floor** (:class:`~audio2pose_ros.console.floor.Floor`): one talker at a time; ``talk``
  takes and releases it. While someone else holds it, only a ``stop`` is accepted.
- **The stop** (:class:`~audio2pose_ros.console.stop.StopHolders`): pressed by anyone, released
  only by whoever pressed it, or, once they have left, by another operator whose ``confirm``
  names them; a stop set outside the console is released with a confirmation naming that.
  Every page is told who holds the stop.
- **The robot's settings**: ``enable``, ``mute`` (the operator's voice out of the robot; the
  stop does not mute it, nor does the mute stop the motion), and the style (``enroll``,
  ``style``, ``style_set``: :class:`~audio2pose_ros.console.learn_style.LearnMyStyle`), while
  the floor is free or the sender's.
- **The style waits for the stop's release**: while the stop is held (by anyone, or set outside
  the console), a change of style (``style``: a preset, "Use my style", the default;
  ``style_set``: the sliders) is refused with the reason, naming who holds the stop, and a style
  learned meanwhile is not applied (its operator is told, :meth:`Room.style_may_change`). So
  the robot resumes after a release in the style it had when its presser stopped it.

A refused action raises :class:`~audio2pose_ros.console.protocol.ProtocolError` with the reason
the page shows. The room sends through the server (``send``), which owns the connections.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Protocol

from audio2pose_ros.console.floor import Floor
from audio2pose_ros.console.learn_style import LearnMyStyle
from audio2pose_ros.console.protocol import Control, ProtocolError, encode
from audio2pose_ros.console.stop import OUTSIDE, StopHolders

__all__ = ["Operator", "Room", "RoomBridge"]


class Operator(Protocol):
    """A connected, identified operator (the server's session)."""

    @property
    def id(self) -> int:
        """The session's number."""

    @property
    def name(self) -> str:
        """The unique name the page gave."""


class RoomBridge(Protocol):
    """What the room needs of the robot's side."""

    def start_talk(self) -> None:
        """A talker took the floor: their audio follows."""

    def end_talk(self) -> None:
        """The talker released the floor (or left): no more audio follows."""

    def set_stop(self, on: bool) -> None:
        """Publish the emergency stop (True) or its release (False)."""

    def set_enable(self, on: bool) -> None:
        """Publish enable."""

    def set_voice_muted(self, on: bool) -> None:
        """Mute (True) or play (False) the operator's voice out of the robot."""

    def status(self) -> dict[str, object]:
        """The graph's status (the room reads ``stop``: whether the robot is stopped)."""


class Room:
    """The floor, the stop and the controls of the connected operators.

    Args:
        bridge: the robot's side.
        learn_style: the style's controls (learned, presets, sliders).
        operators: the operators connected now.
        send: ``send(operator, text)``: a message to one page, not dropped.
        log: ``log(level, message)`` with level ``info`` or ``warning``.
    """

    def __init__(
        self,
        bridge: RoomBridge,
        learn_style: LearnMyStyle,
        operators: Callable[[], Iterable[Operator]],
        send: Callable[[Operator, str], None],
        log: Callable[[str, str], None],
    ) -> None:
        self.bridge = bridge
        self.learn_style = learn_style
        self.operators = operators
        self.send = send
        self.log = log
        self.floor = Floor()
        self.stops = StopHolders()

    def on_control(self, operator: Operator, control: Control) -> None:
        """Act on ``talk``, ``stop``, ``enable``, ``mute``, ``enroll``, ``style`` or ``style_set``.

        Raises:
            ProtocolError: not the operator's to do now (the reason says why).
        """
        on = control.fields.get("on")
        if control.type == "talk":
            self._talk(operator, bool(on))
        elif control.type == "stop":
            self._on_stop(operator, bool(on), control.fields.get("confirm"))
        else:
            if not self.floor.free_for(operator.id):
                raise ProtocolError(
                    f"{self.floor.holder_name} has the floor: only a stop is accepted meanwhile"
                )
            if control.type == "enable":
                self.bridge.set_enable(bool(on))
            elif control.type == "mute":
                self.bridge.set_voice_muted(bool(on))
            else:  # enroll, style, style_set
                if control.type != "enroll" and self.stopped():
                    raise ProtocolError(self._style_waits("style not changed"))
                reply = self.learn_style.on_control(operator.id, operator.name, control)
                if reply is not None:
                    self.send(operator, reply)

    def left(self, operator: Operator) -> None:
        """``operator`` has gone: their floor is released, their presses of STOP stay."""
        if self.floor.release(operator.id):
            self.bridge.end_talk()
            self.send_floor()
        if self.stops.left(operator.id):
            self.log(
                "warning",
                f"console: {operator.name!r} left holding the stop: the robot stays stopped "
                f"until another operator releases it with a confirmation naming them",
            )
            self.send_stop_holders()

    def _talk(self, operator: Operator, on: bool) -> None:
        if on:
            if self.floor.holds(operator.id):
                return
            if not self.floor.take(operator.id, operator.name):
                raise ProtocolError(f"{self.floor.holder_name} has the floor: wait for them")
            self.bridge.start_talk()
        elif self.floor.release(operator.id):
            self.bridge.end_talk()
        else:
            return
        self.send_floor()

    # --- the stop and who holds it -----------------------------------------------------------

    def _on_stop(self, operator: Operator, on: bool, confirm: str | None) -> None:
        """A press of STOP, the release of one's own, or a confirmed one for someone who left.

        Raises:
            ProtocolError: a release that is not the operator's to make (the reason names who
                holds the stop).
        """
        if on:
            if self.stops.press(operator.id, operator.name):
                self.log("warning", f"console: STOP pressed by {operator.name!r}")
            self.bridge.set_stop(True)  # each press latches it again, whatever came meanwhile
            self.send_stop_holders()
            return
        if confirm is None:
            if not self.stops.release(operator.id):
                if self.stops.held or self._stopped_outside():
                    raise ProtocolError(self._stop_refusal())
                return  # nothing held, nothing stopped: nothing to release
            self.log("info", f"console: {operator.name!r} released their stop")
        elif confirm in self.stops.present_holders():
            raise ProtocolError(
                f"{confirm} is still connected: only {confirm} can release their stop"
            )
        elif self.stops.release_absent(confirm):
            self.log(
                "warning",
                f"console: {operator.name!r} released the stop of {confirm!r}, who has left "
                "(confirmed by name)",
            )
        elif confirm == OUTSIDE and not self.stops.held and self._stopped_outside():
            self.log("warning", f"console: {operator.name!r} released a stop set {OUTSIDE}")
        else:
            raise ProtocolError(f"no stop of {confirm!r} to release; {self._stop_refusal()}")
        if not self.stops.held:
            self.bridge.set_stop(False)
        self.send_stop_holders()

    def stopped(self) -> bool:
        """Whether the stop is latched: held by an operator's press, or set outside the console."""
        return self.stops.held or self._stopped_outside()

    def style_may_change(self, operator_id: int) -> bool:
        """Whether a style learned for ``operator_id`` may be applied now (the stop is released).

        While the stop is latched the operator is told that their style waits.
        """
        if not self.stopped():
            return True
        for operator in list(self.operators()):
            if operator.id == operator_id:
                text = self._style_waits("your style is learned but not applied")
                self.send(operator, encode("error", message=f"{text}: then press Use my style"))
        return False

    def _style_waits(self, what: str) -> str:
        """Why a style change waits: the stop and who holds it."""
        present = self.stops.present_holders()
        absent = [p.name for p in self.stops.presses if not p.present]
        holders = ", ".join([*present, *(f"{name} (has left)" for name in absent)])
        stop = f"STOP held by {holders}" if holders else f"STOP set {OUTSIDE}"
        return f"{what}: the robot is stopped ({stop}); change it after the release"

    def _stopped_outside(self) -> bool:
        """Whether the robot is stopped with no press from this console holding it."""
        return not self.stops.held and self.bridge.status().get("stop") is True

    def _stop_refusal(self) -> str:
        """Why a release is not the sender's to make, naming who may make it."""
        present = self.stops.present_holders()
        absent = [p.name for p in self.stops.presses if not p.present]
        if present:
            return f"the stop is held by {', '.join(present)}: only they can release it"
        if absent:
            return (
                f"the stop is held by {', '.join(absent)}, who left: releasing it needs a "
                "confirmation that names them"
            )
        if self._stopped_outside():
            return f"the stop was set {OUTSIDE}: releasing it needs a confirmation naming that"
        return "the robot is not stopped"

    # --- what every page is told ----------------------------------------------------------------

    def stop_holders(self, operator: Operator) -> str:
        """The message that tells a page who holds the stop, and whether it does."""
        return encode("stop_holders", holders=self.stops.view(), you=self.stops.holds(operator.id))

    def send_stop_holders(self) -> None:
        """Tell every page who holds the stop."""
        for operator in list(self.operators()):
            self.send(operator, self.stop_holders(operator))

    def send_floor(self) -> None:
        """Tell every page who has the floor."""
        for operator in list(self.operators()):
            text = encode(
                "floor",
                holder=self.floor.holder_name or None,
                you=self.floor.holds(operator.id),
            )
            self.send(operator, text)

"""Another node's parameters as an operator chose them, kept in force over its parameter services.

:class:`KeptParameters` speaks to one node's ``<node>/set_parameters`` and
``<node>/get_parameters`` for a fixed list of parameters of one type. It sets what the operator
chose, reads every parameter back each :data:`READ_BACK_S` (what really runs, for the page), and,
where a value read back differs from the choice, sets the choice again with a warning in the
log: a node restarted meanwhile (by the supervisor, or ``ros2 launch``'s respawn) comes back with
its start-up values, and the operator's choice must not silently fall away with them.

The console uses one for each thing it sets on another node: the motion filter's style, the
inference node's ``model_path`` and the voice node's ``muted``.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.client import Client
from rclpy.task import Future

from audio2pose_ros.ros.diagnosed_node import DiagnosedNode

__all__ = ["READ_BACK_S", "SET_ANSWER_S", "KeptParameters", "Value"]

READ_BACK_S = 2.0  # the parameters are read back (and the choice set again) this often
# A set unanswered for this long is not waited for any more: its node died before it answered.
SET_ANSWER_S = 5.0

Value = bool | float | str
# The field of a ParameterValue that holds a value of each type handled.
_FIELDS = {
    ParameterType.PARAMETER_BOOL: "bool_value",
    ParameterType.PARAMETER_DOUBLE: "double_value",
    ParameterType.PARAMETER_STRING: "string_value",
}


def _shown(value: Value) -> str:
    return repr(value) if isinstance(value, str) else str(value)


class KeptParameters:
    """Set, read back and keep in force some parameters of another node.

    The choice is per parameter: :meth:`choose` adds to it (a slider moves one parameter of
    the choice), and a parameter the node refuses goes back to the value the node last accepted
    for it (or leaves the choice when it never accepted one); a value set again after a
    read-back and refused stays chosen and is tried at the next read-back. Before the first
    read-back that sees the choice in force, :attr:`values` shows what the node really has.

    Args:
        node: the node that owns the clients and the read-back timer.
        target: the other node's name (relative names resolve in ``node``'s namespace).
        names: the parameters read back, all of type ``kind``.
        kind: a :class:`~rcl_interfaces.msg.ParameterType` (bool, double or string).
        what: what the parameters are, in log lines ("style", "model", "mute").
        unavailable: the problem shown while ``target``'s parameter services are not there.
        keep_own: before the first choice (and the first after each :meth:`restore`), read
            and keep the node's own values, which :meth:`restore` sets again; a choice made
            while the services are not there is then refused, as it cannot be undone.
    """

    def __init__(
        self,
        node: DiagnosedNode,
        target: str,
        names: Sequence[str],
        kind: int,
        what: str,
        unavailable: str,
        keep_own: bool = False,
    ) -> None:
        self.node = node
        self.target = target
        self.names = list(names)
        self.field = _FIELDS[kind]
        self.kind = kind
        self.what = what
        self.unavailable = unavailable
        self.keep_own = keep_own
        self._lock = threading.Lock()
        self._values: dict[str, Value] | None = None  # as last read back
        self._problem = ""  # the last refusal, or unavailable ('' when none)
        self.choice: dict[str, Value] = {}  # the operator's, kept in force
        self.accepted: dict[str, Value] = {}  # what the node last accepted of each
        self.own: dict[str, Value] | None = None  # the node's, before the console changed it
        self.sets = 0  # sets asked for: a read begun before one is not acted on
        self.answered = 0  # sets answered
        self.asked_s = -1e9  # when the last set was asked for (monotonic)
        self.set_client: Client[Any, Any] = node.create_client(
            SetParameters, f"{target}/set_parameters"
        )
        self.get_client: Client[Any, Any] = node.create_client(
            GetParameters, f"{target}/get_parameters"
        )
        node.create_timer(READ_BACK_S, node.guarded(self.refresh))

    @property
    def values(self) -> dict[str, Value] | None:
        """The values read back last; None while the node's services are not there."""
        with self._lock:
            return None if self._values is None else dict(self._values)

    @property
    def problem(self) -> str:
        """Why the last choice is not in force: the node's refusal, or its services absent."""
        with self._lock:
            return self._problem

    def ready(self) -> bool:
        """Whether both of the node's parameter services are there."""
        return self.set_client.service_is_ready() and self.get_client.service_is_ready()

    def choose(
        self, values: Mapping[str, Value], otherwise: Callable[[], None] | None = None
    ) -> None:
        """Set ``values`` (some of the names) and keep them in force from now on.

        ``otherwise`` runs when they are not put in force: refused by the node, or (with
        ``keep_own``) the node's own values could not be read first.

        Raises:
            ValueError: a name not among :attr:`names`.
        """
        unknown = sorted(set(values) - set(self.names))
        if unknown:
            raise ValueError(f"not a parameter kept by this client: {', '.join(unknown)}")
        if not self.keep_own:
            self._chosen(dict(values), otherwise)
            return
        if not self.ready():
            self._unavailable(otherwise)
            return
        with self._lock:
            kept = self.own is not None
        if kept:
            self._chosen(dict(values), otherwise)
            return

        def keep_then_set(future: Future[Any]) -> None:
            own = self._read_values(future)
            if own is None:
                with self._lock:
                    self._problem = f"{self.target}'s {self.what} could not be read"
                if otherwise is not None:
                    otherwise()
                return
            with self._lock:
                if self.own is None:
                    self.own = own
            self._chosen(dict(values), otherwise)

        request = GetParameters.Request(names=self.names)
        self.get_client.call_async(request).add_done_callback(keep_then_set)

    def restore(self) -> None:
        """Set the node's own values (kept before the first choice) again, as the choice.

        Nothing to do when nothing was chosen since the last restore. The next choice reads
        the node's own values afresh.
        """
        if not self.ready():
            self._unavailable(None)
            return
        with self._lock:
            own, self.own = self.own, None
        if own is not None:
            self._chosen(own, None)

    def _unavailable(self, otherwise: Callable[[], None] | None) -> None:
        with self._lock:
            self._problem = self.unavailable
        if otherwise is not None:
            otherwise()

    def _chosen(self, values: dict[str, Value], otherwise: Callable[[], None] | None) -> None:
        with self._lock:
            self.choice.update(values)
        self._set(values, otherwise)

    def _set(self, values: dict[str, Value], otherwise: Callable[[], None] | None) -> None:
        """Ask the node to set ``values``; its answer updates the choice, then a read follows."""
        if not self.set_client.service_is_ready():
            self._unavailable(otherwise)
            return
        with self._lock:
            self.sets += 1
            self.asked_s = time.monotonic()
        request = SetParameters.Request()
        request.parameters = [
            Parameter(name=name, value=ParameterValue(type=self.kind, **{self.field: value}))
            for name, value in values.items()
        ]

        def done(future: Future[Any]) -> None:
            results = getattr(future.result(), "results", [])
            refused = []
            with self._lock:
                self.answered += 1
                for (name, value), result in zip(values.items(), results, strict=False):
                    if result.successful:
                        self.accepted[name] = value
                        continue
                    refused.append(str(result.reason))
                    if self.choice.get(name) == value:  # not chosen anew meanwhile
                        if name in self.accepted:
                            self.choice[name] = self.accepted[name]
                        else:
                            del self.choice[name]
                self._problem = "; ".join(refused)
            if refused:
                self.node.get_logger().warning(
                    f"{self.what} refused by {self.target}: {'; '.join(refused)}"
                )
                if otherwise is not None:
                    otherwise()
            self.refresh()

        self.set_client.call_async(request).add_done_callback(done)

    def refresh(self) -> None:
        """Read the values back; set the choice again where they differ from it."""
        if not self.get_client.service_is_ready():
            with self._lock:
                self._values = None
            return
        with self._lock:
            sets = self.sets
            waiting = self.answered < sets and time.monotonic() - self.asked_s < SET_ANSWER_S
        if waiting:
            return  # the set's own read follows its answer
        request = GetParameters.Request(names=self.names)
        future = self.get_client.call_async(request)
        future.add_done_callback(lambda done: self._read(done, sets))

    def _read(self, future: Future[Any], sets: int) -> None:
        """Keep the values read, unless a set was asked for since the read began."""
        read = self._read_values(future)
        if read is None:
            return
        with self._lock:
            if sets != self.sets:
                return  # read before a set: the set's own read follows
            self._values = read
            again = {name: value for name, value in self.choice.items() if read[name] != value}
            if not again and self._problem == self.unavailable:
                self._problem = ""  # the choice is in force
        if again:
            self.node.get_logger().warning(
                f"{self.target}'s "
                + " and ".join(f"{name} is {_shown(read[name])}" for name in again)
                + ", the operator chose "
                + " and ".join(_shown(value) for value in again.values())
                + ": set again"
            )
            self._set(again, None)

    def _read_values(self, future: Future[Any]) -> dict[str, Value] | None:
        """The values of a get_parameters answer; None unless every name has one of our type."""
        values = getattr(future.result(), "values", [])
        if len(values) != len(self.names) or any(v.type != self.kind for v in values):
            return None
        return {name: getattr(v, self.field) for name, v in zip(self.names, values, strict=True)}

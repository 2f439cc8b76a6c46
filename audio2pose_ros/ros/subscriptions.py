"""How the nodes subscribe: bytes bounded before decoding, message info where rclpy gives it.

Only public rclpy is used, the same on Humble (3.3), Jazzy (7.1) and Kilted (9.1):
``Node.create_subscription(..., raw=True)`` hands a callback the message's serialized bytes, so
one too large is dropped before rclpy decodes it (:func:`bounded_receiver`), and
:func:`~rclpy.serialization.deserialize_message` decodes the others.

**Message info.** Jazzy and Kilted pass a callback of two parameters the message's info: a
mapping with ``source_timestamp`` and ``received_timestamp`` (ns), Jazzy's and Kilted's
``publication_sequence_number``, and on Kilted ``publisher_gid``. Humble's executors pass the
message alone (its ``Subscription`` has no ``CallbackType``), and Kilted's EventsExecutor (opt-in,
:mod:`audio2pose_ros.ros.executor`) fails on a two-parameter callback. There the nodes subscribe
with one parameter and get ``None`` for the info (:func:`info_callback`); what each node does
without it is said where it reads it (:func:`~audio2pose_ros.ros.messages.published_s`,
:func:`~audio2pose_ros.ros.messages.publisher_of`).

**Content filters.** Kilted's rclpy (9.1) takes ``content_filter_options`` (a
``rclpy.subscription_content_filter_options.ContentFilterOptions``) when creating a
subscription, and ``Subscription.is_cft_enabled`` says whether the middleware filters (Fast DDS
does; Cyclone DDS does not); Jazzy's (7.1) and Humble's (3.3) have neither:
:func:`content_filter_options` is None there.

**QoS event handlers.** :func:`quiet_event_callbacks` leaves out rclpy's default handlers, from
``rclpy.event_handler`` (Jazzy, Kilted) or ``rclpy.qos_event`` (Humble).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any

from rclpy.serialization import deserialize_message
from rclpy.subscription import Subscription

from audio2pose_ros.ros.executor import events_executor_requested

MessageInfo = Mapping[str, Any]  # what rclpy passes beside a message (a dict on every distro)
# Whether this rclpy's executors pass a two-parameter callback the message's info (Jazzy, Kilted;
# not Humble). Read once at import; a test sets it False to run the nodes as on Humble.
RCLPY_PASSES_INFO = hasattr(Subscription, "CallbackType")
MAX_PUBLISHERS_TRACKED = 64  # per input: publishers whose sequence numbers are followed


def message_info_delivered() -> bool:
    """Whether a two-parameter callback gets the message's info (this rclpy and executor)."""
    return RCLPY_PASSES_INFO and not events_executor_requested()


def info_callback(receive: Callable[[Any, MessageInfo | None], None]) -> Callable[..., None]:
    """A subscription callback calling ``receive(message, info)``; info None where none comes.

    rclpy tells the two kinds of callback apart by their signature: one of two required
    parameters gets the info, one of one parameter does not.
    """
    if message_info_delivered():

        def with_info(message: Any, info: MessageInfo) -> None:
            receive(message, info)

        return with_info

    def message_only(message: Any) -> None:
        receive(message, None)

    return message_only


def quiet_event_callbacks(kind: str) -> Any:
    """Rclpy's ``PublisherEventCallbacks`` or ``SubscriptionEventCallbacks`` without defaults.

    ``kind`` is ``"Publisher"`` or ``"Subscription"``. Humble has the classes (with
    ``use_default_callbacks``) in ``rclpy.qos_event``, Jazzy and Kilted in ``rclpy.event_handler``.
    """
    try:
        module = importlib.import_module("rclpy.event_handler")
    except ImportError:  # Humble
        module = importlib.import_module("rclpy.qos_event")
    return getattr(module, f"{kind}EventCallbacks")(use_default_callbacks=False)


def content_filter_options(expression: str, parameters: list[str]) -> Any | None:
    """Rclpy's options of a content-filtered subscription; None where rclpy has none.

    ``expression`` is DDS's SQL filter (``"data = %0"``), ``parameters`` its values (``%0``...).
    """
    try:
        module = importlib.import_module("rclpy.subscription_content_filter_options")
    except ImportError:  # Jazzy, Humble
        return None
    return module.ContentFilterOptions(expression, parameters)


class SequenceGaps:
    """Messages the middleware dropped, from each publisher's sequence numbers where rclpy has them.

    Kilted's info carries the publisher's gid and its ``publication_sequence_number``: a gap
    between two numbers of one publisher is a message lost on the way (a best-effort queue that
    kept only the newest). Jazzy has the number without the gid and Humble neither: numbers of
    several publishers cannot be told apart there, so nothing is counted from them and only the
    messages taken and replaced unserved count (:class:`LatestMessage`), unless the caller
    observes only messages of the one publisher it takes them from (``one_source``: the motion
    filter's raw poses, whose second publisher is refused by the graph where rclpy gives no gid).
    """

    def __init__(self, one_source: bool = False) -> None:
        """No publisher heard yet; ``one_source``: numbers without a gid are counted as one's."""
        self.one_source = one_source
        self.last: dict[bytes, int] = {}  # publisher gid -> last sequence number seen
        self.lost = 0

    def observe(self, info: MessageInfo | None) -> None:
        """Count the messages of ``info``'s publisher lost since the last one heard."""
        if info is None:
            return
        sequence = info.get("publication_sequence_number")
        gid = info.get("publisher_gid")
        if not isinstance(sequence, int) or not (isinstance(gid, Mapping) or self.one_source):
            return
        key = bytes(gid.get("data", b"")) if isinstance(gid, Mapping) else b""
        last = self.last.pop(key, None)
        if last is not None and sequence > last + 1:
            self.lost += sequence - last - 1
        if len(self.last) >= MAX_PUBLISHERS_TRACKED:
            del self.last[next(iter(self.last))]  # the longest unheard
        self.last[key] = sequence


def bounded_receiver(
    msg_type: type,
    max_bytes: int | Callable[[], int],
    deliver: Callable[[Any, MessageInfo | None], None],
    oversized: Callable[[int, int], None],
) -> Callable[[bytes, MessageInfo | None], None]:
    """A receiver of serialized messages: one over ``max_bytes`` goes to ``oversized``, undecoded.

    rclpy turns every element of a message into a Python object before a callback sees it: a
    JointTrajectory of 100,000 points takes about a second to decode, during which the node
    serves nothing. ``max_bytes`` is an int or a function giving the current cap;
    ``oversized(n_bytes, cap)`` reports a dropped message; ``deliver(message, info)`` gets the
    others, decoded.
    """

    def receive(data: bytes, info: MessageInfo | None) -> None:
        cap = max_bytes() if callable(max_bytes) else max_bytes
        if len(data) > cap:
            oversized(len(data), cap)
            return
        deliver(deserialize_message(data, msg_type), info)

    return receive


class LatestMessage:
    """An input where the newest message replaces the ones before it (a robot's command).

    Each message is kept as its bytes, replacing the one kept before: the timer that uses the
    input calls :meth:`serve`, which decodes only the newest and passes it to the callback. A
    flood therefore costs the node a take per message and no decoding, and its queue is this one
    slot: no flood grows it. Every message replaced unserved is counted (``superseded``), and
    those the middleware dropped where their sequence numbers say so (:class:`SequenceGaps`).
    """

    def __init__(
        self,
        msg_type: type,
        callback: Callable[[Any], None],
        max_bytes: int,
        oversized: Callable[[int, int], None],
    ) -> None:
        """Pass the newest message to ``callback``; one over ``max_bytes`` goes to ``oversized``."""
        self.msg_type = msg_type
        self.callback = callback
        self.max_bytes = max_bytes
        self.oversized = oversized
        self.newest: bytes | None = None
        self.superseded = 0
        self.gaps = SequenceGaps()

    def receive(self, data: bytes, info: MessageInfo | None) -> None:
        """A message arrived (the subscription's callback): keep it as the newest."""
        self.gaps.observe(info)
        if len(data) > self.max_bytes:
            self.oversized(len(data), self.max_bytes)
            return
        if self.newest is not None:
            self.superseded += 1
        self.newest = data

    def serve(self) -> None:
        """Pass the newest message kept since the last call, decoded, to the callback (if any)."""
        if self.newest is None:
            return
        data, self.newest = self.newest, None
        self.callback(deserialize_message(data, self.msg_type))

    @property
    def dropped(self) -> int:
        """Messages replaced unserved or lost in the middleware (by sequence numbers)."""
        return self.superseded + self.gaps.lost

"""The small types a :class:`truav.bus.transport.Bus` takes and hands out: callback signatures, the
fault-injection :class:`LinkFilter` hook (and its default :class:`PassThrough`), :class:`BusStats` and
:class:`Handle`."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import zenoh

from truav.wire.schema import Message

BUS_LOGGER = "truav.bus.transport"
"""The logger every part of the Bus logs to (its log lines kept the name they had in one module)."""
log = logging.getLogger(BUS_LOGGER)

CLOSE_JOIN_TIMEOUT_S = 2.0
UNKNOWN_SRC = "?"

DataCallback = Callable[[str, Message, bytes, int], None]  # (key, msg, raw, recv_time_ns)
RawCallback = Callable[[str, bytes, int], None]  # (key, raw, recv_time_ns)
KeyCallback = Callable[[str], None]  # liveliness: (token key)


# --- link filter (fault-injection hook) ----------------------------------------------
class LinkFilter(Protocol):
    """Decides the fate of each incoming message on the receiving Bus.

    Called one message at a time (under the Bus's filter lock), once per message, with
    ``dst`` = the Bus identity and ``now_ns`` = arrival time (Bus clock).
    ``src`` is the sender id, or :data:`UNKNOWN_SRC` for unreadable raw
    payloads.  Returns ``(deliver, delay_s)``.

    A filter may also have a ``passes_everything`` attribute: while it is
    true the Bus's inboxes skip the filter (their arrival path stays a
    timestamp and an append).
    """

    def decide(self, key: str, src: str, dst: str, now_ns: int) -> tuple[bool, float]: ...


class PassThrough:
    """The default link filter: deliver everything now."""

    passes_everything = True

    def decide(self, key: str, src: str, dst: str, now_ns: int) -> tuple[bool, float]:
        return True, 0.0


@dataclass(frozen=True)
class BusStats:
    """A snapshot of a Bus's receive-side counters."""

    received: int = 0  # samples that reached this Bus (data + raw subscriptions + inboxes)
    delivered: int = 0  # user callbacks that returned normally (data, raw, liveliness) + valid messages drained
    filtered: int = 0  # dropped by the link filter
    delayed: int = 0  # delayed by the link filter
    malformed: dict[str, int] = field(default_factory=dict)  # dropped, by reason
    callback_errors: int = 0
    filter_errors: int = 0
    overflow: int = 0  # dropped because max_pending deliveries were queued, or evicted from a full inbox
    backoffs: int = 0  # pauses of a ring subscription's pump under a flood of refused messages (Bus.receive_ring)
    rejected: dict[str, dict[str, int]] = field(default_factory=dict)  # {reason: {sender: n}}, bounded senders
    sent: dict[str, int] = field(default_factory=dict)  # messages this Bus put with publish(), by kind

    @property
    def dropped_malformed(self) -> int:
        return sum(self.malformed.values())


class Handle:
    """Something declared on a Bus (subscription, token); ``close()`` undeclares it."""

    def __init__(self, what: str, undeclare: Callable[[], None]) -> None:
        self.what = what
        self._undeclare: Callable[[], None] | None = undeclare

    @property
    def closed(self) -> bool:
        return self._undeclare is None

    def close(self) -> None:
        undeclare, self._undeclare = self._undeclare, None
        if undeclare is not None:
            try:
                undeclare()
            except zenoh.ZError as exc:  # session already closed: nothing left to undeclare
                log.debug("undeclaring %s: %s", self.what, exc)

    def __repr__(self) -> str:
        return f"Handle({self.what!r}, closed={self.closed})"


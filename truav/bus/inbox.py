"""An inbox: messages that arrive cheaply and are decoded when their reader asks.

A subscriber callback costs a Python thread wake-up plus decoding per message
(about 100 us of CPU under load on a 2-core VM, measured with
``bench/bench_swarm.py``).  With 20 agents each hearing 19 beacons per tick,
that fan-out kept both cores busy right when beacons should go out and was
most of the beacon-latency tail.  An agent reads its neighbours' beacons once
per decision, so the :class:`Inbox` only stamps the arrival time and appends
the sample; :meth:`Inbox.drain` decodes and validates them on the reader's
thread, in arrival order.

With a fault-injection link filter on the bus, the filter still decides at
arrival (so emulated loss and delay are timed by arrival, as for
``Bus.subscribe``): dropped messages never enter, delayed ones become visible
at their due time and carry it as their receive time.

Create one with ``Bus.inbox(key_expr)``.
"""

from __future__ import annotations

import heapq
import itertools
import threading
import time
from collections import deque
from typing import NamedTuple, Protocol

import zenoh

from truav.bus.placement import _FACTS
from truav.wire import schema
from truav.wire.schema import Message

DEFAULT_INBOX_CAPACITY = 4096
"""Messages held before the oldest are evicted (counted as overflow): 10 s of 20 agents' beacons at 10 Hz."""


class InboxBus(Protocol):
    """What an inbox uses of its :class:`truav.bus.transport.Bus` (which imports this module)."""

    def _clock(self) -> int: ...
    def _filters_nothing(self) -> bool: ...
    def _count_received(self, n: int, delivered: int | None = None) -> None: ...
    def _count_overflow(self) -> None: ...
    def _refuse_replayed(self, key: str, sample: zenoh.Sample) -> bool: ...
    def _payload(self, key: str, sample: zenoh.Sample, max_bytes: int | None) -> bytes | None: ...
    def _admit(self, key: str, raw: bytes, arrival_ns: int) -> float | None: ...
    def _decode(self, key: str, raw: bytes) -> Message | None: ...


class Received(NamedTuple):
    """One valid message taken from an inbox."""

    key: str
    msg: Message
    raw: bytes
    recv_ns: int
    """Arrival time on the bus clock (for a delayed message: when its delay ended)."""


_tuple_new = tuple.__new__  # _tuple_new(Received, fields) is Received(*fields) without NamedTuple's __new__
_PUT = zenoh.SampleKind.PUT
_MAX_PAYLOAD_BYTES = schema.MAX_PAYLOAD_BYTES


class Inbox:
    """Valid messages on one key expression, decoded by :meth:`drain` on the reader's thread."""

    def __init__(self, bus: InboxBus, capacity: int = DEFAULT_INBOX_CAPACITY, compact: bool = True) -> None:
        """``compact``: a full inbox first validates what it holds and keeps the valid messages
        (nothing valid is lost to junk: lock-step); False: it just evicts the oldest (real time: only
        the freshest beacons matter, and a flood then costs no decoding until the reader drains)."""
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        self._bus = bus
        self._compacts = compact
        # Entries: (recv_ns, zenoh.Sample) unfiltered, or (recv_ns, key, raw) after the link filter.
        self._ready: deque[tuple] = deque(maxlen=capacity)
        self._capacity = capacity
        self._delayed: list[tuple[int, int, int, str, bytes]] = []  # (due mono ns, seq, recv_ns, key, raw)
        self._seq = itertools.count()
        self._cond = threading.Condition(threading.Lock())
        self._waiting = False
        self._want = 1  # a waiter is woken once this many messages are ready (Inbox.wait's min_ready)

    # -- arrival: the Bus's pump thread for the subscription, kept to a clock read and an append --
    def on_sample(self, sample: zenoh.Sample) -> None:
        bus = self._bus
        recv_ns = bus._clock()
        if bus._filters_nothing():
            ready = self._ready
            if len(ready) < self._capacity:  # not full: what _push does then, without its call
                ready.append((recv_ns, sample))
            else:
                self._push((recv_ns, sample))
        else:
            self._filtered_arrival(sample, recv_ns)
        # Read after the append: a waiter that set them already sees the entry or gets woken.
        if self._waiting and len(self._ready) >= self._want:
            with self._cond:
                self._cond.notify_all()

    def _push(self, entry: tuple) -> None:
        if self._compacts and len(self._ready) == self._ready.maxlen:
            self._compact()
        if len(self._ready) == self._ready.maxlen:  # deque evicts the oldest
            try:
                oldest = self._ready[0]
            except IndexError:  # drained meanwhile: nothing is evicted
                oldest = None
            if oldest is not None:
                self._bus._count_overflow()
                if len(oldest) == 2:  # an unfiltered sample is counted as received when drained, or here
                    self._bus._count_received(1, delivered=0)
        self._ready.append(entry)

    def _compact(self) -> None:
        """A full inbox validates what it holds and keeps only valid messages (decoded).

        Only a flood fills an inbox that its reader drains every cycle: without this, junk
        would evict the valid messages waiting among it (a lock-step agent would then miss a
        neighbour's beacon).  Costs one decode per waiting message, and only when full."""
        entries = []
        while True:
            try:
                entries.append(self._ready.popleft())
            except IndexError:
                break
        valid = [v for v in map(self._validate, entries) if v is not None]
        self._ready.extend(valid)

    def _validate(self, entry: tuple) -> tuple | None:
        """``(recv_ns, key, raw, msg)`` for a valid entry, None (counted by the bus) otherwise."""
        if len(entry) == 4:
            return entry
        if len(entry) == 2:
            recv_ns, sample = entry
            self._bus._count_received(1, delivered=0)
            if sample.kind != zenoh.SampleKind.PUT:
                return None
            key = str(sample.key_expr)
            if self._bus._refuse_replayed(key, sample):
                return None
            raw = self._bus._payload(key, sample, schema.MAX_PAYLOAD_BYTES)
            if raw is None:
                return None
        else:
            recv_ns, key, raw = entry
        msg = self._bus._decode(key, raw)
        return None if msg is None else (recv_ns, key, raw, msg)

    def _filtered_arrival(self, sample: zenoh.Sample, recv_ns: int) -> None:
        if sample.kind != zenoh.SampleKind.PUT:
            return
        arrival_mono = time.monotonic_ns()
        key = str(sample.key_expr)
        if self._bus._refuse_replayed(key, sample):
            self._bus._count_received(1, delivered=0)
            return
        raw = self._bus._payload(key, sample, schema.MAX_PAYLOAD_BYTES)
        delay_s = None if raw is None else self._bus._admit(key, raw, recv_ns)
        self._bus._count_received(1, delivered=0)  # counted here; drain counts only what it delivers
        if delay_s is None:
            return
        if delay_s <= 0:
            self._push((recv_ns, key, raw))
            return
        delay_ns = int(delay_s * 1e9)
        with self._cond:
            heapq.heappush(self._delayed, (arrival_mono + delay_ns, next(self._seq), recv_ns + delay_ns, key, raw))

    # -- the reader's side --
    def drain(self) -> list[Received]:
        """Every valid message that has arrived (and whose delay, if any, is over), oldest first.

        Malformed messages are dropped and counted by the bus, as for ``Bus.subscribe``."""
        entries: list[tuple] = []
        ready, take = self._ready, entries.append
        while ready:
            try:
                take(ready.popleft())
            except IndexError:  # a full inbox compacting itself on the arrival thread took it
                break
        arrived = len(entries)
        if self._delayed:
            now = time.monotonic_ns()
            with self._cond:
                while self._delayed and self._delayed[0][0] <= now:
                    _, _, recv_ns, key, raw = heapq.heappop(self._delayed)
                    entries.append((recv_ns, key, raw))
        out: list[Received] = []
        keep = out.append
        unfiltered = 0
        bus = self._bus
        decode = bus._decode
        known = _FACTS.get
        new, received = _tuple_new, Received
        for entry in entries:  # the hot loop (an agent drains its neighbours' beacons each tick): all inline
            if len(entry) == 2:
                recv_ns, sample = entry
                if sample.kind != _PUT:
                    continue
                unfiltered += 1
                key = str(sample.key_expr)
                if sample.attachment is not None and bus._refuse_replayed(key, sample):
                    continue
                payload = sample.payload
                facts = known(key)
                size = len(payload)
                if facts is not None and size <= facts[3] and size <= _MAX_PAYLOAD_BYTES:
                    raw = payload.to_bytes()
                else:  # a key not seen yet, or too large for it: the bus's own check (and count)
                    raw = bus._payload(key, sample, _MAX_PAYLOAD_BYTES)
                    if raw is None:
                        continue
            elif len(entry) == 4:  # validated when the inbox was full
                keep(new(received, (entry[1], entry[3], entry[2], entry[0])))
                continue
            else:
                recv_ns, key, raw = entry
            msg = decode(key, raw)
            if msg is not None:
                keep(new(received, (key, msg, raw, recv_ns)))
        if entries:
            self._bus._count_received(unfiltered, delivered=len(out))
        if len(entries) > arrived:  # delayed ones interleave by when they were due
            out.sort(key=lambda r: r.recv_ns)
        return out

    def wait(self, timeout: float, min_ready: int = 1) -> bool:
        """Block until a message may be ready to drain, at most ``timeout`` seconds; True if one may be.

        ``min_ready``: sleep through arrivals until this many messages are ready (a lock-step agent
        missing k beacons needs at least k more; waking for each of a 100-agent swarm's beacons
        cost more than the beacons themselves)."""
        with self._cond:
            self._want = max(1, min_ready)
            self._waiting = True  # set before looking, so an arrival after the look notifies
            try:
                if len(self._ready) >= self._want:
                    return True
                if self._delayed:
                    timeout = min(timeout, max(0.0, (self._delayed[0][0] - time.monotonic_ns()) / 1e9))
                if timeout > 0:
                    self._cond.wait(timeout)
                return bool(self._ready) or bool(self._delayed and self._delayed[0][0] <= time.monotonic_ns())
            finally:
                self._waiting = False
                self._want = 1

    def __len__(self) -> int:
        """Messages waiting (delayed ones included), before validation."""
        return len(self._ready) + len(self._delayed)


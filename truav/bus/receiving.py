"""The receiving side of a :class:`truav.bus.transport.Bus` (a mixin): subscriptions, their pump threads
(see the thread model in :mod:`truav.bus.transport`), inboxes and the recorder's pull receiver."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import zenoh

from truav.bus.bus_types import BUS_LOGGER, DataCallback, Handle, PassThrough, RawCallback, UNKNOWN_SRC
from truav.bus.inbox import DEFAULT_INBOX_CAPACITY, Inbox
from truav.bus.placement import size_limit_of_key
from truav.bus.publishing import REPLAY_TAG
from truav.wire import keys, schema
from truav.wire.guard import R_REPLAYED
from truav.wire.schema import SchemaError

log = logging.getLogger(BUS_LOGGER)

DEFAULT_RECEIVE_FIFO = 256
"""Samples a FIFO subscription holds in Zenoh before it pushes back (zenoh-python's own default)."""
REALTIME_RECEIVE_RING = 256
"""Samples a real-time process's subscription holds in Zenoh before the oldest are dropped (Bus.receive_ring):
far more than a tick brings (an observation, a tick, one action or beacon per UAV), few enough that a flood
cannot make a message wait behind more than this many others."""
PUMP_BATCH = 64
PUMP_BACKOFF_S = 0.02
"""A ring subscription's pump that refused (or, into a full inbox, evicted for) more than half of its last
PUMP_BATCH samples (a flood) pauses this long: the ring then drops the flood inside Zenoh, so junk costs a
process a bounded share of a core (64 samples per pause, some 5%) whatever its rate, and a valid message
behind it waits at most this much longer. (The count is per Bus: a flood on one key can pause another.)"""

DEFAULT_PULL_CAPACITY = 65_536
PULL_IDLE_SLEEP_S = 0.001


class RawReceiver:
    """Pulls (key, payload, recv_time_ns) from a FIFO subscriber; one consumer thread only."""

    def __init__(self, sub: zenoh.Subscriber, bus: "Receiving") -> None:
        self._sub, self._bus = sub, bus

    def try_recv(self) -> tuple[str, bytes, int] | None:
        """The next sample, or None if none is waiting. Its receive time is when it is pulled."""
        while True:
            sample = self._sub.try_recv()
            while sample is not None and sample.kind != zenoh.SampleKind.PUT:
                sample = self._sub.try_recv()
            if sample is None:
                return None
            key = str(sample.key_expr)
            # Not even a recorder keeps a payload too large for its key's kind: checked before copying.
            limit = size_limit_of_key(key)
            payload = sample.payload
            if len(payload) > limit:
                self._bus._count_received(1, delivered=0)
                self._bus._count_malformed(key, SchemaError(schema.R_TOO_LARGE, f"{len(payload)} bytes, "
                                                            f"limit {limit}", src=None))
                continue
            self._bus._count_received(1)
            return key, payload.to_bytes(), self._bus._clock()

    def recv(self, timeout: float) -> tuple[str, bytes, int] | None:
        """The next sample, waiting up to ``timeout`` seconds (polling at 1 ms)."""
        deadline = time.monotonic() + timeout
        while True:
            item = self.try_recv()
            if item is not None or time.monotonic() >= deadline:
                return item
            time.sleep(PULL_IDLE_SLEEP_S)



class Receiving:
    """Bus methods that subscribe and pump: uses the Bus's ``_session``, ``_identity``, ``_clock``,
    ``_lock``, ``_deliver_lock``, ``_pumps``, ``_received``, ``_shed``, ``_closed``, ``_filter``,
    ``accept_replay``, ``receive_ring``, its ``_register`` and the :class:`~truav.bus.delivery.Delivery` methods."""

    def _refuse_replayed(self, key: str, sample: zenoh.Sample) -> bool:
        """True (counted) if ``sample`` was put by a replay and this Bus does not accept replays."""
        att = sample.attachment
        if att is None or self.accept_replay or att.to_bytes() != REPLAY_TAG:
            return False
        self._count_malformed(key, SchemaError(R_REPLAYED, "replayed traffic in a live run (accept_replay is off)",
                                               src=keys.SRC_REPLAY))
        return True

    # -- subscribing --
    def subscribe(self, key_expr: str, callback: DataCallback) -> Handle:
        """Deliver decoded, valid messages on ``key_expr`` as ``callback(key, msg, raw, recv_time_ns)``.

        Malformed payloads and payloads that do not belong on their key are
        dropped, counted by reason and logged once per reason.  ``recv_time_ns``
        is the Bus clock when the message arrived from Zenoh, or at delivery
        for a message the link filter delayed.
        """
        return self._declare_data(key_expr, lambda key, raw, arr_ns, arr_mono: self._on_data(
            key, raw, arr_ns, arr_mono, callback), max_bytes=schema.MAX_PAYLOAD_BYTES)

    def subscribe_raw(self, key_expr: str, callback: RawCallback) -> Handle:
        """Deliver every payload on ``key_expr`` undecoded as ``callback(key, raw, recv_time_ns)`` (recorder).

        The link filter still applies, with the sender read from the envelope
        when possible (:data:`UNKNOWN_SRC` otherwise).
        """
        return self._declare_data(key_expr, lambda key, raw, arr_ns, arr_mono: self._on_raw(
            key, raw, arr_ns, arr_mono, callback))

    def receive_raw(self, key_expr: str, capacity: int = DEFAULT_PULL_CAPACITY) -> "RawReceiver":
        """A pull receiver of raw payloads on ``key_expr`` (the recorder's fast path).

        Samples queue in a bounded Zenoh FIFO and are pulled by one consumer
        thread: no Python callback or delivery thread per message. When the
        consumer lags, the full FIFO pushes back on Zenoh's own queues
        (BLOCK publishers slow down, DROP ones drop at the source), so nothing
        is dropped silently in this process. No link filter applies (a
        recorder records what the bus carried); refused when one is set.
        """
        if not isinstance(self._filter, PassThrough):
            raise ValueError("receive_raw records what the bus carried: not available with a link filter")
        sub = self._session.declare_subscriber(key_expr, zenoh.handlers.FifoChannel(capacity))
        receiver = RawReceiver(sub, self)
        self._register(Handle(f"pull subscriber {key_expr}", sub.undeclare))
        return receiver

    def inbox(self, key_expr: str, capacity: int = DEFAULT_INBOX_CAPACITY, compact: bool = True) -> Inbox:
        """An :class:`~truav.bus.inbox.Inbox` of valid messages on ``key_expr``, decoded when drained.

        For traffic a process reads once per cycle (an agent's neighbour
        beacons): arrival costs a timestamp and an append, not a callback.
        The link filter applies at arrival, as for :meth:`subscribe`. ``compact``: see
        :class:`~truav.bus.inbox.Inbox`.
        """
        box = Inbox(self, capacity, compact=compact)
        self.feed(box, key_expr)
        return box

    def feed(self, box: Inbox, key_expr: str) -> Handle:  # box: anything with Inbox.on_sample
        """Also put what arrives on ``key_expr`` into ``box`` (an agent's range-limited beacon cells
        come and go as it moves); ``close()`` the returned handle to stop."""
        return self._pump(key_expr, box.on_sample, f"inbox {key_expr}")

    def poll_subscribe(self, key_expr: str, callback: DataCallback, capacity: int = 16) -> Callable[[], int]:
        """:meth:`subscribe` without a thread, for messages that come seldom (the world's rejections): samples wait
        in a ring of ``capacity`` inside Zenoh (a flood drops the oldest there, without Python) until the returned
        ``drain()`` decodes, checks and delivers them on the caller's thread; it returns how many it took.
        (A Zenoh callback subscriber would cost a thread as well: zenoh-python runs each on its own.)"""
        on_sample = self._sample_handler(lambda key, raw, arr_ns, arr_mono: self._on_data(
            key, raw, arr_ns, arr_mono, callback), schema.MAX_PAYLOAD_BYTES)
        sub = self._session.declare_subscriber(key_expr, zenoh.handlers.RingChannel(capacity))
        self._register(Handle(f"polled subscriber {key_expr}", sub.undeclare))
        handler = sub.handler

        def drain() -> int:
            taken = 0
            while taken < capacity:
                try:
                    sample = handler.try_recv()
                except zenoh.ZError:  # undeclared, or the session closed
                    return taken
                if sample is None:
                    return taken
                on_sample(sample)
                taken += 1
            return taken

        return drain

    def _declare_data(
        self, key_expr: str, handle: Callable[[str, bytes, int, int], None], max_bytes: int | None = None
    ) -> Handle:
        return self._pump(key_expr, self._sample_handler(handle, max_bytes), f"subscriber {key_expr}")

    def _sample_handler(self, handle: Callable[[str, bytes, int, int], None],
                        max_bytes: int | None) -> Callable[[zenoh.Sample], None]:
        """What a subscription does with each sample: count it, refuse replayed or oversized ones, ``handle`` the rest."""
        def on_sample(sample: zenoh.Sample) -> None:  # zenoh-python's callback thread: keep it short
            if sample.kind != zenoh.SampleKind.PUT:
                return
            arrival_ns, arrival_mono = self._clock(), time.monotonic_ns()
            key = str(sample.key_expr)
            with self._lock:
                self._received += 1
            if self._refuse_replayed(key, sample):
                return
            raw = self._payload(key, sample, max_bytes)
            if raw is None or self._closed:
                return
            with self._deliver_lock:  # one message at a time through filter and callback
                handle(key, raw, arrival_ns, arrival_mono)

        return on_sample

    def _pump(self, key_expr: str, on_sample: Callable[[zenoh.Sample], None], what: str) -> Handle:
        """Subscribe ``key_expr`` into a bounded Zenoh channel (FIFO, or a ring with :attr:`receive_ring`)
        and start its pump thread, which hands each sample to ``on_sample`` (see the module docstring)."""
        ring = self.receive_ring
        handler = zenoh.handlers.RingChannel(ring) if ring else zenoh.handlers.FifoChannel(DEFAULT_RECEIVE_FIFO)
        sub = self._session.declare_subscriber(key_expr, handler)
        handle = self._register(Handle(what, sub.undeclare))
        # The pump reads the handler, not the subscriber: a thread blocked in Subscriber.recv holds a borrow
        # of it that makes undeclare fail ("Already borrowed"); undeclaring ends the handler's recv instead.
        pump = threading.Thread(target=self._run_pump, args=(sub.handler, on_sample, what, bool(ring)), daemon=True,
                                name=f"truav-rx[{self._identity}] {key_expr}")
        with self._lock:
            self._pumps.append(pump)
        pump.start()
        return handle

    def _run_pump(self, sub: zenoh.handlers.Handler, on_sample: Callable[[zenoh.Sample], None], what: str,
                  backs_off: bool) -> None:
        while True:
            try:
                sample = sub.recv()  # waits with the GIL released
                taken, shed = 0, self._shed
                while sample is not None:
                    try:
                        on_sample(sample)
                    except Exception as exc:  # the handlers guard user code; this is a last resort
                        if self._first(f"pump:{what}:{type(exc).__name__}"):
                            log.exception("bus %s: %s failed on a sample (%r); continuing", self._identity, what, exc)
                    taken += 1
                    if taken == PUMP_BATCH:
                        if backs_off and 2 * (self._shed - shed) > PUMP_BATCH:  # a flood: let the ring drop it
                            self._count_backoff()
                            time.sleep(PUMP_BACKOFF_S)
                        taken, shed = 0, self._shed
                    sample = sub.try_recv()  # the rest of a batch without giving up the GIL per sample
            except zenoh.ZError:  # undeclared, or the session closed
                return

    def _payload(self, key: str, sample: zenoh.Sample, max_bytes: int | None) -> bytes | None:
        """The sample's bytes; None (counted as too large) above ``max_bytes``, checked before copying."""
        size = len(sample.payload)
        if max_bytes is not None:
            max_bytes = min(max_bytes, size_limit_of_key(key))  # the key's kind says how large it may be
        if max_bytes is not None and size > max_bytes:
            self._count_malformed(key, SchemaError(schema.R_TOO_LARGE, f"{size} bytes, limit {max_bytes}"))
            return None
        return sample.payload.to_bytes()

    def _on_data(self, key: str, raw: bytes, arrival_ns: int, arrival_mono: int, callback: DataCallback) -> None:
        msg = self._decode(key, raw)
        if msg is not None:
            self._route(key, msg.src, arrival_ns, arrival_mono, lambda recv_ns: callback(key, msg, raw, recv_ns))

    def _on_raw(self, key: str, raw: bytes, arrival_ns: int, arrival_mono: int, callback: RawCallback) -> None:
        src = schema.peek_src(raw) or UNKNOWN_SRC
        self._route(key, src, arrival_ns, arrival_mono, lambda recv_ns: callback(key, raw, recv_ns))


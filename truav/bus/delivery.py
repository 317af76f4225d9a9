"""Delivery and accounting of a :class:`truav.bus.transport.Bus` (a mixin): decoding and checking a
message, the link filter's verdict, delivering now or through the scheduler, and the counters of what was
received, delivered and refused (logged once per reason)."""

from __future__ import annotations

import logging
import math
from collections.abc import Callable

from truav.bus.bus_types import BUS_LOGGER, UNKNOWN_SRC
from truav.bus.placement import _FACTS, check_placed, facts_of
from truav.wire import schema
from truav.wire.codec import decode
from truav.wire.schema import Message, SchemaError

log = logging.getLogger(BUS_LOGGER)

MAX_LOG_ONCE_TAGS = 1024  # distinct "log once" tags remembered; tags can hold sender-chosen keys


class Delivery:
    """Bus methods that decode, filter, deliver and count: uses the Bus's ``_lock``, ``_deliver_lock``,
    ``_filter_lock``, ``_filter``, ``_identity``, ``_clock``, ``_sched``, ``_logged``, its counters,
    ``rejections`` and ``guard``."""

    def _count_received(self, n: int, delivered: int | None = None) -> None:
        with self._lock:
            self._received += n
            self._delivered += n if delivered is None else delivered

    def _decode(self, key: str, raw: bytes) -> Message | None:
        """The valid message ``raw`` carries on ``key``, or None (dropped, counted, logged once per reason)."""
        facts = _FACTS.get(key)
        if facts is None:
            facts = facts_of(key)
        try:
            msg = decode(raw, facts[0])
            check_placed(facts, key, msg)
            guard = self.guard
            verdict = guard.check(key, msg) if guard is not None else None
            if verdict is not None:
                raise SchemaError(verdict[0], verdict[1], src=msg.src)
        except SchemaError as exc:
            self._count_malformed(key, exc)
            return None
        return msg

    def _filters_nothing(self) -> bool:
        return getattr(self._filter, "passes_everything", False)

    def _admit(self, key: str, raw: bytes, arrival_ns: int) -> float | None:
        """The link filter's verdict on a raw message (see :meth:`_decide`), for an inbox."""
        return self._decide(key, schema.peek_src(raw) or UNKNOWN_SRC, arrival_ns)

    def _route(self, key: str, src: str, arrival_ns: int, arrival_mono: int, deliver: Callable[[int], None]) -> None:
        """Apply the link filter, then deliver now or schedule for later.

        ``deliver(recv_ns)`` gets the arrival time for a message delivered now
        and the delivery time for one the filter delayed."""
        delay_s = self._decide(key, src, arrival_ns)
        if delay_s is None:
            return
        if delay_s <= 0:
            self._invoke(key, lambda: deliver(arrival_ns))
            return
        job = lambda: self._invoke(key, lambda: deliver(self._clock()))  # noqa: E731
        if not self._sched.submit(arrival_mono + int(delay_s * 1e9), job):
            self._count_overflow()

    def _decide(self, key: str, src: str, arrival_ns: int) -> float | None:
        """The link filter's verdict: None to drop, else the delay in s (counted as filtered / delayed).

        A filter that raises or returns a bad delay fails open (delivered now,
        counted, logged once)."""
        try:
            with self._filter_lock:
                ok, delay_s = self._filter.decide(key, src, self._identity, arrival_ns)
            delay_s = float(delay_s)
            if not math.isfinite(delay_s) or delay_s < 0:
                raise ValueError(f"delay_s={delay_s} must be finite and >= 0")
        except Exception as exc:  # a broken filter must not silence the bus: fail open
            with self._lock:
                self._filter_errors += 1
            if self._first(f"filter:{type(exc).__name__}"):
                log.warning("link filter failed on %s from %s (%r); delivering anyway", key, src, exc)
            ok, delay_s = True, 0.0
        if not ok:
            with self._lock:
                self._filtered += 1
            return None
        if delay_s > 0:
            with self._lock:
                self._delayed += 1
        return delay_s

    def _invoke(self, key: str, deliver: Callable[[], None]) -> None:
        try:
            with self._deliver_lock:
                deliver()
        except Exception as exc:
            with self._lock:
                self._callback_errors += 1
            if self._first(f"callback:{key}:{type(exc).__name__}"):
                log.exception("bus %s: callback for %s raised %r; continuing (repeats only counted)",
                              self._identity, key, exc)
        else:
            with self._lock:
                self._delivered += 1

    def _count_malformed(self, key: str, exc: SchemaError) -> None:
        """Count a refused message by reason (``malformed``) and by reason and sender (``rejections``,
        which logs once per sender and reason)."""
        with self._lock:
            self._malformed[exc.reason] = self._malformed.get(exc.reason, 0) + 1
            self._shed += 1
        self.rejections.add(exc.reason, exc.src, key, str(exc))
        told = getattr(self, "on_refused", None)
        if told is not None:
            told(key, exc)

    def _count_backoff(self) -> None:
        with self._lock:
            self._backoffs += 1
        if self._first("backoff"):
            log.warning("bus %s: flooded with messages it refuses; its receive rings drop the excess inside Zenoh "
                        "(pauses only counted from now on)", self._identity)

    def _count_overflow(self) -> None:
        with self._lock:
            self._overflow += 1
            self._shed += 1
        if self._first("overflow"):
            log.warning("bus %s: delivery queue full, dropping messages (only counted from now on)", self._identity)

    def _first(self, tag: str) -> bool:
        """True the first time ``tag`` is seen: the log-once-per-reason gate."""
        with self._lock:
            if tag in self._logged or len(self._logged) >= MAX_LOG_ONCE_TAGS:
                return False
            self._logged.add(tag)
            return True


"""The publishing side of a :class:`truav.bus.transport.Bus` (a mixin): the permission check of a key,
stamping and encoding, and the cache of declared Zenoh publishers."""

from __future__ import annotations

import time

import zenoh

from truav.bus.placement import check_placement, congestion_control
from truav.wire import keys, schema
from truav.wire.schema import Message

REPLAY_TAG = b"truav-replay"
"""Zenoh attachment on every put of a ``replay`` Bus: receivers drop it unless they accept replays."""
MAX_CACHED_PUBLISHERS = 4096

_WILDCARD_CHARS = frozenset("*$?#")


class Publishing:
    """Bus methods that put: uses the Bus's ``_prefix``, ``_uav``, ``_run``, ``_seq``, ``_lock``,
    ``_closed``, ``_publishers``, ``_sent``, ``_session``, ``_tag`` and ``guard``."""

    def check_publish(self, key: str) -> str:
        """Return ``key`` if this identity may publish (or declare a token) on it.

        ValueError for a non-concrete key; PermissionError outside this run or,
        for ``uav/<i>``, outside ``uav/<i>/``, ``alive/uav/<i>`` and the batch keys ``group/<i>-<j>/beacons``.
        """
        if not isinstance(key, str) or not key or _WILDCARD_CHARS.intersection(key) or "//" in key:
            raise ValueError(f"cannot publish on {key!r}: need a concrete key without wildcards")
        if not key.startswith(self._prefix):
            raise PermissionError(f"{self._identity} may not publish on {key!r}: outside {self._prefix}")
        if self._uav is not None:
            own = keys.uav_prefix(self._run, self._uav) + "/"
            group = keys.parse_group(key)  # a batch of beacons: only its group's first UAV sends it
            if not key.startswith(own) and key != keys.alive_uav(self._run, self._uav) \
                    and not (group is not None and group[0] == self._uav):
                raise PermissionError(
                    f"{self._identity} may only publish under {own} and {keys.alive_uav(self._run, self._uav)}, "
                    f"not on {key!r}"
                )
        return key

    def publish(self, key: str, msg: Message, pad_to: int | None = None) -> Message:
        """Stamp ``msg`` (src=identity, next seq, t=clock), encode and put it; return the stamped message.

        ``pad_to``: a message with a ``pad`` field (state, command) is padded to that many bytes
        once stamped (:func:`truav.wire.schema.padded`). PermissionError/ValueError from
        :meth:`check_publish`; SchemaError if ``msg`` does not belong on ``key`` (receivers would drop it).
        """
        self.check_publish(key)
        stamped = self._seq.stamp(msg)
        if pad_to is not None:
            stamped = schema.padded(stamped, pad_to)
        check_placement(key, stamped)
        self._put(key, schema.encode(stamped))
        with self._lock:  # counted once handed to Zenoh: what a receiver could have got
            self._sent[stamped.KIND] = self._sent.get(stamped.KIND, 0) + 1
        if self.guard is not None:
            self.guard.sent(stamped)
        return stamped

    def prepare(self, *keys_: str) -> None:
        """Declare the publishers of ``keys_`` now, so a process's first message on each is not
        slowed by the declaration (a round trip to the router, seen as a latency spike at tick 0)."""
        for key in keys_:
            self._publisher(self.check_publish(key))

    def await_subscribers(self, key: str, timeout: float) -> bool:
        """Wait until someone subscribes to ``key`` (at most ``timeout`` s); whether anyone does.

        A one-shot sender (`truav-swarm down`) needs it: a freshly declared publisher drops
        what it puts until its router has told it of a matching subscriber, which over
        linked routers takes longer than opening the session."""
        pub = self._publisher(self.check_publish(key))
        deadline = time.monotonic() + timeout
        while pub is not None and not pub.matching_status.matching:
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.02)
        return True

    def publish_raw(self, key: str, data: bytes) -> None:
        """Put pre-encoded bytes as they are (replay, tests); same permission check, no validation."""
        self._put(self.check_publish(key), bytes(data))

    def _publisher(self, key: str) -> zenoh.Publisher | None:
        """The cached publisher of ``key``, declared on first use (None once the cache is full)."""
        with self._lock:
            if self._closed:
                raise RuntimeError(f"bus {self._identity} is closed")
            pub = self._publishers.get(key)
            if pub is None and len(self._publishers) < MAX_CACHED_PUBLISHERS:
                pub = self._publishers[key] = self._session.declare_publisher(
                    key, congestion_control=congestion_control(key))
            return pub

    def _put(self, key: str, data: bytes) -> None:
        pub = self._publisher(key)
        try:
            if pub is not None:
                pub.put(data, attachment=self._tag)
            else:
                self._session.put(key, data, congestion_control=congestion_control(key), attachment=self._tag)
        except zenoh.ZError:
            if self._closed:  # close() ran between the check and the put: the same error as putting after it
                raise RuntimeError(f"bus {self._identity} is closed") from None
            raise

"""Liveliness of a :class:`truav.bus.transport.Bus` (a mixin): declaring tokens, watching them come
and go, and asking which are alive."""

from __future__ import annotations

import time

import zenoh

from truav.bus.bus_types import Handle, KeyCallback

DEFAULT_ALIVE_TIMEOUT_S = 1.0
ALIVE_EMPTY_RETRY_S = (0.005, 0.01, 0.02, 0.05, 0.1)  # pauses before re-asking an empty liveliness query


class Liveliness:
    """Bus methods on liveliness tokens: uses the Bus's ``_session``, ``_sched``, ``_invoke``,
    ``_count_overflow``, ``check_publish`` and ``_register``."""

    # -- liveliness --
    def declare_liveliness(self, token_key: str) -> Handle:
        """Declare a liveliness token (same permission rules as publish); it dies with the session."""
        token = self._session.liveliness().declare_token(self.check_publish(token_key))
        return self._register(Handle(f"token {token_key}", token.undeclare))

    def watch_liveliness(self, key_expr: str, on_join: KeyCallback, on_leave: KeyCallback) -> Handle:
        """Call ``on_join(key)`` / ``on_leave(key)`` as tokens on ``key_expr`` appear / vanish.

        Tokens alive at declaration are reported as joins (history).  Runs on the
        scheduler thread under the delivery lock; the link filter does not apply.
        """
        def on_sample(sample: zenoh.Sample) -> None:
            key = str(sample.key_expr)
            cb = on_join if sample.kind == zenoh.SampleKind.PUT else on_leave
            if not self._sched.submit(time.monotonic_ns(), lambda: self._invoke(key, lambda: cb(key))):
                self._count_overflow()

        sub = self._session.liveliness().declare_subscriber(key_expr, on_sample, history=True)
        return self._register(Handle(f"liveliness watch {key_expr}", sub.undeclare))

    def alive(self, key_expr: str, timeout: float = DEFAULT_ALIVE_TIMEOUT_S) -> list[str]:
        """Keys of the liveliness tokens currently alive on ``key_expr`` (blocks up to ``timeout`` s).

        A snapshot; use :meth:`watch_liveliness` to track membership.  In
        zenoh 1.10 a liveliness query sent within a few ms of another session
        joining or leaving the router can come back empty at once although
        tokens exist (longer under CPU load), so an empty answer is re-asked a
        few times (:data:`ALIVE_EMPTY_RETRY_S`, ~185 ms in all, within
        ``timeout``) before it is believed.
        """
        deadline = time.monotonic() + timeout
        found = self._query_tokens(key_expr, deadline)
        for pause in ALIVE_EMPTY_RETRY_S:
            if found or time.monotonic() + pause >= deadline:
                break
            time.sleep(pause)
            found = self._query_tokens(key_expr, deadline)
        return sorted(found)

    def _query_tokens(self, key_expr: str, deadline: float) -> set[str]:
        found = set()
        left = max(deadline - time.monotonic(), 0.0)
        for reply in self._session.liveliness().get(key_expr, timeout=left):
            sample = reply.ok
            if sample is not None:
                found.add(str(sample.key_expr))
        return found

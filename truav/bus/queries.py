"""Request and answer on a :class:`truav.bus.transport.Bus` (a mixin): a Zenoh queryable that serves
one key, and a query that asks it.

Both sides bound what they take: a query payload or an answer larger than ``max_bytes`` is refused
(answered with an error, or raised), at most :data:`MAX_PENDING_QUERIES` queries wait for the handler
(more are answered ``busy`` at once), and the handler runs on a thread of its own, never on Zenoh's
callback thread, so it may take a moment (a replay applying a seek) without stalling the session.
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable

import zenoh

from truav.bus.bus_types import Handle

log = logging.getLogger("truav.bus.queries")

MAX_PENDING_QUERIES = 16
DEFAULT_MAX_QUERY_BYTES = 4096
DEFAULT_ASK_TIMEOUT_S = 5.0

Answer = tuple[bool, bytes]
"""(ok, payload): ok False sends the payload as a Zenoh reply error (one line of UTF-8 text)."""
QueryHandler = Callable[[bytes], Answer]


class QueryRefused(RuntimeError):
    """A query that got no answer, an error answer, or an answer too large."""


class Queries:
    """Bus methods that serve and send queries: uses the Bus's ``_session``, ``check_publish``, ``_register``
    and ``_identity``."""

    def serve(self, key: str, handler: QueryHandler, max_bytes: int = DEFAULT_MAX_QUERY_BYTES) -> Handle:
        """Answer every query on ``key`` with ``handler(payload)`` (same permission rules as publish)."""
        key = self.check_publish(key)
        pending: queue.Queue[zenoh.Query | None] = queue.Queue(MAX_PENDING_QUERIES)

        def on_query(query: zenoh.Query) -> None:  # Zenoh's callback thread: hand over, never wait
            try:
                pending.put_nowait(query)
            except queue.Full:
                _answer(query, key, (False, b"busy: too many queries waiting"))

        def work() -> None:
            while (query := pending.get()) is not None:
                payload = query.payload
                data = b"" if payload is None else payload.to_bytes()
                if len(data) > max_bytes:
                    answer: Answer = (False, f"query of {len(data)} bytes, limit {max_bytes}".encode())
                else:
                    try:
                        answer = handler(data)
                    except Exception as exc:  # a handler bug must not kill the server: say it, once per query
                        log.exception("query handler on %s failed", key)
                        answer = (False, f"internal error: {type(exc).__name__}: {exc}".encode())
                _answer(query, key, answer)

        worker = threading.Thread(target=work, name=f"truav-queries[{key}]", daemon=True)
        worker.start()
        queryable = self._session.declare_queryable(key, on_query)

        def undeclare() -> None:
            try:
                queryable.undeclare()
            finally:
                while True:  # what still waits gets an answer now, and the worker its end at once
                    try:
                        waiting = pending.get_nowait()
                    except queue.Empty:
                        break
                    if waiting is not None:
                        _answer(waiting, key, (False, b"closing: the server stopped"))
                pending.put(None)
                worker.join(DEFAULT_ASK_TIMEOUT_S)

        return self._register(Handle(f"queryable {key}", undeclare))

    def ask(self, key: str, payload: bytes, timeout: float = DEFAULT_ASK_TIMEOUT_S,
            max_bytes: int = DEFAULT_MAX_QUERY_BYTES) -> bytes:
        """The first answer to a query on ``key``; QueryRefused when none comes within ``timeout`` s,
        when it is an error (its text) or when it is larger than ``max_bytes``."""
        for reply in self._session.get(key, payload=payload, timeout=timeout):
            if reply.ok is not None:
                data = reply.ok.payload.to_bytes()
                if len(data) > max_bytes:
                    raise QueryRefused(f"{key}: answer of {len(data)} bytes, limit {max_bytes}")
                return data
            text = reply.err.payload.to_bytes()[:max_bytes].decode(errors="replace") if reply.err else "error"
            raise QueryRefused(text)
        raise QueryRefused(f"no answer on {key} within {timeout:g} s (nothing serves it: is the replay running, "
                           f"on this run and router?)")


def _answer(query: zenoh.Query, key: str, answer: Answer) -> None:
    ok, data = answer
    try:
        with query:  # finalizes the query (its replies end) on leaving
            if ok:
                query.reply(key, data)
            else:
                query.reply_err(data)
    except zenoh.ZError as exc:  # the asker gave up or the session closed
        log.debug("answering a query on %s: %s", key, exc)

"""`-v` debug lines at a rate a person can read: what a process received, decided and sent, at most
one line per period and call site (a swarm process handles 10-100 messages a second)."""

from __future__ import annotations

import logging
import time

DEBUG_PERIOD_S = 1.0
"""At most one debug line a second per call site: each line sums up what happened since the last one."""


class Every:
    """``if every.due(): log.debug(...)``: True at most once per ``period_s``, and only when ``logger``
    shows debug lines (so building the line costs nothing without -v); logger None: always (a caller
    that prints its lines itself, the supervisor)."""

    def __init__(self, logger: logging.Logger | None, period_s: float = DEBUG_PERIOD_S, clock=time.monotonic):
        self.logger, self.period_s, self.clock = logger, period_s, clock
        self._next = float("-inf")

    def due(self) -> bool:
        if self.logger is not None and not self.logger.isEnabledFor(logging.DEBUG):
            return False
        now = self.clock()
        if now < self._next:
            return False
        self._next = now + self.period_s
        return True

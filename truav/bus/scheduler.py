"""A Bus's scheduler: one thread running jobs in due-time order (delayed deliveries, liveliness
changes), so emulated link delays cost no extra threads."""

from __future__ import annotations

import heapq
import itertools
import logging
import threading
import time
from collections.abc import Callable

from truav.bus.bus_types import BUS_LOGGER, CLOSE_JOIN_TIMEOUT_S

log = logging.getLogger(BUS_LOGGER)


class Scheduler:
    """One thread running zero-argument jobs in due-time order (FIFO among equals)."""

    def __init__(self, name: str, max_pending: int) -> None:
        self._heap: list[tuple[int, int, Callable[[], None]]] = []
        self._counter = itertools.count()
        self._cond = threading.Condition()
        self._max_pending = max_pending
        self._running = True
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    def submit(self, due_mono_ns: int, job: Callable[[], None]) -> bool:
        """Queue ``job``; False if stopped or full."""
        with self._cond:
            if not self._running or len(self._heap) >= self._max_pending:
                return False
            heapq.heappush(self._heap, (due_mono_ns, next(self._counter), job))
            self._cond.notify()
            return True

    def in_thread(self) -> bool:
        return threading.current_thread() is self._thread

    def _loop(self) -> None:
        while True:
            with self._cond:
                while self._running:
                    if not self._heap:
                        self._cond.wait()
                        continue
                    wait_ns = self._heap[0][0] - time.monotonic_ns()
                    if wait_ns <= 0:
                        break
                    self._cond.wait(wait_ns / 1e9)
                if not self._running:
                    return
                _, _, job = heapq.heappop(self._heap)
            try:
                job()
            except Exception:  # jobs guard user code themselves; this is a last resort
                log.exception("bus delivery job failed")

    def stop(self) -> None:
        with self._cond:
            self._running = False
            self._heap.clear()
            self._cond.notify_all()
        if not self.in_thread():
            self._thread.join(CLOSE_JOIN_TIMEOUT_S)


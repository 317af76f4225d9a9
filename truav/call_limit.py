"""A bound on the time one call into a user's agent class may take (agents.api ``call_limit_s``).

A hung or slow class then fails, named, instead of stalling a lock-step run or a training. On the main
thread a SIGALRM timer interrupts the call (a pure-Python loop at once; code inside one C call, a numpy
operation say, when that returns). Off the main thread no timer can interrupt it: the call is measured
and fails when it returns late. Pure: no I/O.
"""

from __future__ import annotations

import signal
import threading
import time
from typing import Any, Callable

MAX_CALL_LIMIT_S = 60.0
"""The largest ``call_limit_s`` a class may declare."""


class CallTooLong(BaseException):
    """A call ran past its limit. A BaseException, so that a user's ``except Exception`` does not swallow it."""

    def __init__(self, limit_s: float):
        super().__init__(f"took longer than {limit_s:g} s (its call_limit_s)")
        self.limit_s = limit_s


def limit_problem(value: Any) -> str | None:
    """What is wrong with a class's ``call_limit_s``, or None."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value <= MAX_CALL_LIMIT_S:
        return f"call_limit_s must be a number of seconds in (0, {MAX_CALL_LIMIT_S:g}], got {value!r}"
    return None


def call_limited(limit_s: float, fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(*args)``, or CallTooLong when it takes longer than ``limit_s`` seconds."""
    if threading.current_thread() is not threading.main_thread():
        start = time.perf_counter()
        result = fn(*args)
        if time.perf_counter() - start > limit_s:
            raise CallTooLong(limit_s)
        return result

    def expired(_signum: int, _frame: object) -> None:
        raise CallTooLong(limit_s)

    previous = signal.signal(signal.SIGALRM, expired)
    try:
        signal.setitimer(signal.ITIMER_REAL, limit_s)
        try:
            return fn(*args)
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0.0)
    finally:
        signal.signal(signal.SIGALRM, previous)


__all__ = ["CallTooLong", "MAX_CALL_LIMIT_S", "call_limited", "limit_problem"]

"""A bound on the time one call into a user's agent class may take (agents.api ``call_limit_s``).

A hung or slow class then fails, named, instead of stalling a lock-step run or a training. On the main
thread a SIGALRM timer interrupts the call (a pure-Python loop at once; code inside one C call, a numpy
operation say, when that returns). Off the main thread no timer can interrupt it: the call is measured
and fails when it returns late. ``call_limited`` bounds one call; ``CallBound`` a sweep of many (the
trainer's calls into every UAV's instance), each as call_limited would, at one timer's price. Pure: no I/O.
"""

from __future__ import annotations

import signal
import threading
import time
from typing import Any, Callable

try:  # signal.signal is this C function plus enum conversions of the handlers given and returned, which
    # cost more than a whole sweep of calls that do nothing (CallBound installs its handler once a sweep)
    from _signal import signal as _set_handler
except ImportError:  # another Python: the wrapper itself
    _set_handler = signal.signal

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


class CallBound:
    """``call_limited`` for many calls in a row at one timer's price: ``with CallBound(limit_s) as call:`` then
    ``call(fn, *args)`` any number of times, each bounded by ``limit_s`` as by call_limited.

    The in-process trainer calls every UAV's act and learn each step; a timer set and a handler installed per
    call cost more than a call that does nothing. Here the handler is installed and the timer armed once for
    the block; each call only notes its start. When the timer fires during a call that has run ``limit_s``,
    that call fails (CallTooLong, as call_limited's); otherwise the timer is re-armed for the running call's
    deadline (it always fires at or before the running call's deadline, armed for an earlier or the same
    call's). Off the main thread, where no timer can interrupt, a call fails when it returns late, as with
    call_limited."""

    def __init__(self, limit_s: float):
        self.limit_s = float(limit_s)
        self._start: float | None = None
        self._previous: Any = None
        self._armed = False

    def __enter__(self) -> Callable[..., Any]:
        if threading.current_thread() is not threading.main_thread():
            return self._measured
        self._previous = _set_handler(signal.SIGALRM, self._expired)
        self._armed = True
        signal.setitimer(signal.ITIMER_REAL, self.limit_s)
        return self._alarmed

    def __exit__(self, *exc: object) -> None:
        self._start = None
        if self._armed:
            self._armed = False
            signal.setitimer(signal.ITIMER_REAL, 0.0)
            _set_handler(signal.SIGALRM, self._previous)

    def _expired(self, _signum: int, _frame: object) -> None:
        if not self._armed:  # fired as the block ended: no timer may outlive it
            return
        start, now = self._start, time.perf_counter()
        if start is not None and now - start >= self.limit_s:
            self._start = None
            raise CallTooLong(self.limit_s)
        left = self.limit_s if start is None else self.limit_s - (now - start)
        signal.setitimer(signal.ITIMER_REAL, max(left, 1e-4))

    def _alarmed(self, fn: Callable[..., Any], *args: Any) -> Any:
        """On the main thread: the timer interrupts a call at its deadline (see _expired)."""
        self._start = _now()
        try:
            return fn(*args)
        finally:
            self._start = None

    def _measured(self, fn: Callable[..., Any], *args: Any) -> Any:
        """Off the main thread (no timer can interrupt): a call fails when it returns late."""
        start = _now()
        result = fn(*args)
        if _now() - start > self.limit_s:
            raise CallTooLong(self.limit_s)
        return result


_now = time.perf_counter


__all__ = ["CallBound", "CallTooLong", "MAX_CALL_LIMIT_S", "call_limited", "limit_problem"]

"""truav.call_limit: a bound on one call into a user's agent class (agents.api call_limit_s)."""

from __future__ import annotations

import signal
import threading
import time

import pytest

from truav.call_limit import MAX_CALL_LIMIT_S, CallBound, CallTooLong, call_limited, limit_problem


def _spin_swallowing():
    try:
        while True:
            pass
    except Exception:  # a class's catch-all must not swallow the limit
        return "swallowed"


def test_a_hung_call_on_the_main_thread_is_interrupted_even_through_a_catch_all():
    start = time.monotonic()
    with pytest.raises(CallTooLong, match=r"took longer than 0.05 s \(its call_limit_s\)"):
        call_limited(0.05, _spin_swallowing)
    assert time.monotonic() - start < 30  # interrupted, not run to the end (generous: a busy machine)


def test_a_call_within_its_limit_returns_its_value_and_leaves_no_timer():
    assert call_limited(5.0, lambda a, b: a + b, 2, 3) == 5
    time.sleep(0.1)  # a timer left armed would fire here and fail the test


def test_off_the_main_thread_a_late_call_fails_when_it_returns():
    results = []

    def worker():
        try:
            results.append(call_limited(0.01, time.sleep, 0.2))
        except CallTooLong as exc:
            results.append(exc)
        results.append(call_limited(5.0, lambda: "fast"))

    t = threading.Thread(target=worker)
    t.start()
    t.join(30)
    assert isinstance(results[0], CallTooLong) and results[1] == "fast"


@pytest.mark.parametrize("value", [0, -1, True, MAX_CALL_LIMIT_S + 1, "1", None, float("nan")])
def test_a_bad_limit_is_named(value):
    assert limit_problem(value) == f"call_limit_s must be a number of seconds in (0, {MAX_CALL_LIMIT_S:g}], " \
                                   f"got {value!r}"


@pytest.mark.parametrize("value", [0.001, 1, 1.0, MAX_CALL_LIMIT_S])
def test_a_good_limit_passes(value):
    assert limit_problem(value) is None


def test_a_block_bounds_each_call_not_their_sum_and_leaves_no_timer():
    """CallBound (the trainer's sweep over every UAV): five calls of 0.15 s under a 0.5 s limit all return,
    although together they take longer than it; afterwards the handler is the one before and no timer is left."""
    before = signal.getsignal(signal.SIGALRM)
    with CallBound(0.5) as call:
        got = [call(lambda i: time.sleep(0.15) or i, i) for i in range(5)]
    assert got == [0, 1, 2, 3, 4]
    assert signal.getsignal(signal.SIGALRM) is before and signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0)
    time.sleep(0.6)  # a timer left armed would fire here


def test_a_hung_call_in_a_block_is_interrupted_even_through_a_catch_all():
    before = signal.getsignal(signal.SIGALRM)
    start = time.monotonic()
    with pytest.raises(CallTooLong, match=r"took longer than 0.05 s"):
        with CallBound(0.05) as call:
            assert call(lambda: "first") == "first"
            call(_spin_swallowing)
    assert time.monotonic() - start < 30  # interrupted, not run to the end (generous: a busy machine)
    assert signal.getsignal(signal.SIGALRM) is before and signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0)


def test_off_the_main_thread_a_late_call_in_a_block_fails_when_it_returns():
    results = []

    def worker():
        with CallBound(0.05) as call:
            results.append(call(lambda: "fast"))
            try:
                call(time.sleep, 0.2)
            except CallTooLong as exc:
                results.append(exc)

    t = threading.Thread(target=worker)
    t.start()
    t.join(30)
    assert results[0] == "fast" and isinstance(results[1], CallTooLong)

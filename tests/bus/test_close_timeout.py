"""Zenoh's close can time out on a loaded machine (eclipse-zenoh/zenoh#2675: ZError "close operation timed
out"). A router asked to stop, and a bus closing, log it and finish their own shutdown: a loaded CI run's
router once exited 1 from it, with "cannot listen" as its message, and chaos judged the run unsound."""

from __future__ import annotations

import logging
import threading

import zenoh

from truav.bus import router


class _SlowClosingSession:
    def zid(self):
        return "test"

    def close(self):
        raise zenoh.ZError("close operation timed out")


def test_a_router_whose_close_times_out_stops_without_error(monkeypatch, caplog):
    monkeypatch.setattr(router, "open_router", lambda *a, **k: _SlowClosingSession())
    stop = threading.Event()
    stop.set()
    with caplog.at_level(logging.WARNING):
        router.run_router(["tcp/127.0.0.1:0"], stop=stop)  # returns: no exception
    assert "close did not finish" in caplog.text and "timed out" in caplog.text


class _TimingOut:
    """A session whose close does close, then reports a time-out, as zenoh#2675's does."""

    def __init__(self, session):
        self._session = session

    def __getattr__(self, name):
        return getattr(self._session, name)

    def close(self):
        self._session.close()
        raise zenoh.ZError("close operation timed out")


def test_a_bus_whose_close_times_out_still_stops_its_threads(bus_factory, caplog):
    bus = bus_factory("world")
    bus._session = _TimingOut(bus._session)
    with caplog.at_level(logging.WARNING):
        bus.close()
    assert bus.closed and "close did not finish" in caplog.text
    assert not any(p.is_alive() for p in bus._pumps)  # the pumps were still joined after the failed close

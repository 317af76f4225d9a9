"""Processes started by ``truav-swarm up`` stop when their supervisor is gone.

The supervisor starts its children in sessions of their own (so Ctrl-C
reaches it alone) and stops them by PID.  Killed itself (SIGKILL, the OOM
killer, a closed terminal), it cannot, so each child also watches it: the
supervisor's PID comes in :data:`SUPERVISOR_PID_ENV`, and when that process
exits the child stops as it does on SIGTERM (an agent checkpoints, the
recorder closes its MCAP file).  A process started by hand has no such
variable and is not watched.

The watch blocks on a Linux pidfd, so it costs no wake-ups; elsewhere it
polls the parent PID every :data:`POLL_PERIOD_S`.  :func:`signals_handled`
is the other half: how a process turns SIGTERM and friends into its own stop.

:class:`StopReasons` and :func:`stop_on_sigterm_or_orphaned` are the lifecycle of a
swarm part (world, controller, view, router): one ``stop()`` on SIGTERM, on a lost
supervisor and on a lost router, with the first reason logged and kept.
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Mapping

log = logging.getLogger("truav.swarm")  # the swarm parts' logger: their stop lines keep its name

SUPERVISOR_PID_ENV = "TRUAV_SUPERVISOR_PID"
def supervisor_pid(environ: Mapping[str, str] = os.environ) -> int | None:
    """The PID in :data:`SUPERVISOR_PID_ENV`, or None if unset or not a positive integer."""
    value = environ.get(SUPERVISOR_PID_ENV, "")
    return int(value) if value.isdigit() and int(value) > 0 else None


def child_env(environ: Mapping[str, str] = os.environ) -> dict[str, str]:
    """The environment for a child of this process that should stop when this process is gone."""
    return {**environ, SUPERVISOR_PID_ENV: str(os.getpid())}


def watch_supervisor(on_gone: Callable[[], None]) -> threading.Thread | None:
    """If this process has a supervisor, call ``on_gone()`` once, from a daemon thread, when it exits.

    Returns the thread, or None when there is nothing to watch (no supervisor
    named, or it is not this process's parent: started by hand with a stale
    environment)."""
    pid = supervisor_pid()
    if pid is None or os.getppid() != pid:
        return None
    thread = threading.Thread(target=_watch, args=(pid, on_gone), name="supervisor-watch", daemon=True)
    thread.start()
    return thread


def _watch(pid: int, on_gone: Callable[[], None]) -> None:
    fd = _pidfd(pid)
    try:
        # Opened while the parent is still `pid`, the pidfd cannot refer to a later process with a reused PID.
        if fd is not None and os.getppid() == pid:
            select.select([fd], [], [])  # readable once the process has exited
        else:
            while os.getppid() == pid:  # re-parented once the supervisor is gone
                time.sleep(POLL_PERIOD_S)
    finally:
        if fd is not None:
            os.close(fd)
    on_gone()


def _pidfd(pid: int) -> int | None:
    try:
        return os.pidfd_open(pid)
    except (AttributeError, OSError):  # not Linux >= 5.3, or the process is already gone
        return None


@contextlib.contextmanager
def signals_handled(signals: Iterable[signal.Signals], handler: Callable[[int, object], None]) -> Iterator[None]:
    """Handle ``signals`` with ``handler`` while the block runs, then restore the previous handlers.

    Python delivers signals to the main thread only; elsewhere this does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {sig: signal.signal(sig, handler) for sig in signals}
    try:
        yield
    finally:
        for sig, previous in old.items():
            signal.signal(sig, previous)


DEFAULT_ROUTER_TIMEOUT_S = 10.0
"""A world or agent that has had no router this long stops (agents checkpoint first)."""
ROUTER_POLL_S = 0.5


def watch_router(session, timeout_s: float, on_lost: Callable[[float], None],
                 poll_s: float = ROUTER_POLL_S) -> threading.Thread | None:
    """Call ``on_lost(seconds_without_router)`` once, from a daemon thread, when this Zenoh client
    session has been connected to no router for ``timeout_s`` seconds.

    A session connected to no router at the start (peer mode) is not watched: returns None.
    Without this, a process whose router died would wait for messages forever."""
    if not list(session.info.routers_zid()):
        return None
    thread = threading.Thread(target=_watch_router, args=(session, timeout_s, on_lost, poll_s),
                              name="router-watch", daemon=True)
    thread.start()
    return thread


def _watch_router(session, timeout_s: float, on_lost: Callable[[float], None], poll_s: float) -> None:
    lost_since = None
    while True:
        time.sleep(poll_s)
        try:
            connected = bool(list(session.info.routers_zid()))
        except Exception:  # the session was closed: the process is stopping anyway
            return
        now = time.monotonic()
        if connected:
            lost_since = None
        elif lost_since is None:
            lost_since = now
        elif now - lost_since >= timeout_s:
            on_lost(now - lost_since)
            return


EXIT_ROUTER_LOST = 1
"""Exit code of a part that stopped because its router was gone."""


class StopReasons:
    """Why a part stopped: the first reason is logged and kept (the logs say why a process ended)."""

    def __init__(self, stop) -> None:
        self._stop = stop
        self.first: str | None = None
        self.router_lost = False

    def because(self, reason: str) -> None:
        if self.first is None:
            self.first = reason
            log.info("stopping: %s", reason)
        self._stop()


def stop_on_sigterm_or_orphaned(stop, bus=None, router_timeout_s: float | None = None) -> StopReasons:
    """``stop()`` on SIGTERM, when the `truav-swarm up` that started this process is gone, and
    (with ``bus``) when the router has been gone for ``router_timeout_s``."""
    reasons = StopReasons(stop)
    signal.signal(signal.SIGTERM, lambda *_: reasons.because("SIGTERM"))
    watch_supervisor(lambda: reasons.because("the truav-swarm up that started this process is gone"))
    if bus is not None and router_timeout_s is not None:
        def router_lost(seconds: float) -> None:
            reasons.router_lost = True
            log.error("no router for %.1f s (it stopped, or the network to it is down)", seconds)
            reasons.because(f"router lost for {seconds:.1f} s")
        watch_router(bus.session, router_timeout_s, router_lost)
    return reasons


def exit_after_work(code: int) -> None:
    """End a bus process whose work is done and written, without the interpreter's finalization.

    Zenoh's own threads may still call into Python while the interpreter finalizes; glibc then aborts the
    process ("FATAL: exception not rethrown", exit -6) after every file was written, and the run reports a
    part that did its work as failed (seen once in ~115 world processes). What finalization would still
    do is done here: non-daemon threads joined, logs and standard streams flushed."""
    for thread in threading.enumerate():
        if thread is not threading.current_thread() and not thread.daemon:
            thread.join()
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)

"""How a command stops: the signals that stop it, the exit code that says which, and workers that cannot
outlive their parent. Base layer: no I/O beyond the signal itself, imported by trainers and processes alike."""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import signal

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""What stops a long-running command as Ctrl-C does: schedulers (Slurm, systemd, `timeout`, container
runtimes) send SIGTERM, a closed terminal SIGHUP."""


INTERRUPTS = (KeyboardInterrupt, SystemError)
"""What a stop signal can surface as: KeyboardInterrupt, or a SystemError wrapping it when it arrived inside a C
extension (numba loading a cached kernel on its first call). Catch these, then keep only :func:`is_interrupt`."""


def is_interrupt(exc: BaseException) -> bool:
    """Whether ``exc`` is Ctrl-C or a stop signal: a KeyboardInterrupt, or an exception raised because one
    arrived inside an extension that wraps it (numba's kernel loader makes it a SystemError whose cause is the
    interrupt); anything else is a bug and keeps its traceback."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def exit_code_for(signum: int) -> int:
    """The shell's exit code of a command stopped by ``signum``: 130 for Ctrl-C, 143 for SIGTERM, 129 for
    SIGHUP. The command still finished its files first."""
    return 128 + int(signum)


_stopped_by: list[int] = []  # signals are process-wide: so is the record of the one that stopped a command


def note_stop_signal(signum: int) -> None:
    """Record that ``signum`` stopped this command (the first one counts), for :func:`stopped_by`."""
    if not _stopped_by:
        _stopped_by.append(int(signum))


def stopped_by() -> int | None:
    """The signal recorded by :func:`note_stop_signal` since :func:`forget_stop_signal`, if any."""
    return _stopped_by[0] if _stopped_by else None


def forget_stop_signal() -> None:
    _stopped_by.clear()


def signal_name(signum: int) -> str:
    return "Ctrl-C" if signum == signal.SIGINT else signal.Signals(signum).name


_PR_SET_PDEATHSIG = 1


def die_with_parent(parent_pid: int) -> None:
    """Have the kernel SIGKILL this process when its parent dies, however the parent dies (SIGKILL and the
    OOM killer included): a worker must not go on training and writing checkpoints for no one. Call it
    first thing in a forked worker, with the parent's PID read before the fork. Linux only; elsewhere
    the parent's own cleanup stays the only guard.

    It also gives SIGTERM and SIGHUP back their default action: a forked worker inherits the parent's
    Python handlers (stop as on Ctrl-C), and the parent ends its workers with SIGTERM."""
    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_DFL)
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    except (OSError, AttributeError):
        return
    if os.getppid() != parent_pid:  # the parent died before the prctl: nobody would send the signal
        os._exit(1)
POLL_PERIOD_S = 0.5

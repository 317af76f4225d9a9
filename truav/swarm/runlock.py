"""The lock a live run holds on its output directory: ``<out>/.truav-run.lock``, flock'ed by the process
that writes the directory (`truav-swarm up`'s supervisor, `chaos`) from before it touches a file until its
summary is written.

Another command that would write there (`up --force`, `up --resume`, `chaos`) sees the lock held and is
refused (truav.swarm.outdir says so). The kernel releases a flock when its holder ends in any way, SIGKILL
included, so a killed run leaves no stale lock. The file stays (removing it would race with the next
taker); it holds the holder's run name, command and PID, for the refusal to name it.

Within one process the lock is re-entrant (chaos holds its subruns' directories; each subrun's
`run_swarm` takes its own again): flock would otherwise refuse the second open of the same file.
"""

from __future__ import annotations

import fcntl
import json
import os
from pathlib import Path

LOCK_FILE = ".truav-run.lock"
MAX_INFO_BYTES = 4096
"""The holder's description is a few dozen bytes: a bigger file is someone else's and not read further."""

_held: dict[str, list[int]] = {}  # resolved lock path -> [fd, depth] of the locks this process holds


def _key(out: Path) -> str:
    return str((out / LOCK_FILE).resolve())


def holder(out: Path) -> dict | None:
    """The description of the live process holding ``out``'s lock (another one than this process), or None
    when no one holds it. Touches nothing: no lock file, no lock taken beyond an instant (a shared one)."""
    path = out / LOCK_FILE
    if not path.is_file() or _key(out) in _held:
        return None
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW)
    except OSError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return _info(fd)
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


def _info(fd: int) -> dict:
    try:
        info = json.loads(os.pread(fd, MAX_INFO_BYTES, 0))
    except (OSError, ValueError):
        info = None
    return info if isinstance(info, dict) else {}


def acquire(out: Path, info: dict) -> dict | None:
    """Take ``out``'s lock for this process (making ``out``) and write ``info`` (run, command) into it with
    this PID; None once held, else the live holder's description (the lock not taken)."""
    key = _key(out)
    if key in _held:
        _held[key][1] += 1
        return None
    out.mkdir(parents=True, exist_ok=True)
    fd = os.open(out / LOCK_FILE, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        theirs = _info(fd)
        os.close(fd)
        return theirs
    os.ftruncate(fd, 0)
    os.pwrite(fd, json.dumps({**info, "pid": os.getpid()}).encode(), 0)
    _held[key] = [fd, 1]
    return None


def release(out: Path) -> None:
    """Give back one hold of ``out``'s lock (the last one unlocks it)."""
    key = _key(out)
    entry = _held.get(key)
    if entry is None:
        return
    entry[1] -= 1
    if entry[1] == 0:
        del _held[key]
        fcntl.flock(entry[0], fcntl.LOCK_UN)
        os.close(entry[0])


def held_here(out: Path) -> bool:
    """Whether this process holds ``out``'s lock."""
    return _key(out) in _held

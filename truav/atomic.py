"""Files replaced whole: written to a temporary of this process's own (its PID in the name: two writers of
one file never share a temporary), fsynced, then renamed over the old file. A failed write (a full disk)
removes its temporary and leaves the old file as it was: the last good checkpoint is never replaced by
a partial one."""

from __future__ import annotations

import errno
import os
from collections.abc import Callable
from contextlib import suppress
from pathlib import Path
from typing import BinaryIO

NO_SPACE = (errno.ENOSPC, errno.EDQUOT)
EXIT_NO_SPACE = 28
"""Exit code of a swarm process that could not write a checkpoint or statistics for want of space (ENOSPC's
number): `truav-swarm up` names it "no space left", since the process's own log line may not fit either."""


def tmp_path(path: str | os.PathLike) -> Path:
    p = Path(path)
    return p.with_name(f"{p.name}.{os.getpid()}.tmp")


def write_atomic(path: str | os.PathLike, write: Callable[[BinaryIO], None]) -> None:
    """``write(f)`` into a temporary beside ``path``, then replace ``path`` by it (raises what the write raised)."""
    tmp = tmp_path(path)
    try:
        with open(tmp, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        with suppress(OSError):
            tmp.unlink()
        if isinstance(exc, OSError) and exc.filename is None:  # a write's error names no file: name the one meant
            exc.filename = os.fspath(path)
        raise


def write_atomic_text(path: str | os.PathLike, text: str) -> None:
    write_atomic(path, lambda f: f.write(text.encode()))


def no_space(exc: BaseException) -> bool:
    return isinstance(exc, OSError) and exc.errno in NO_SPACE


def no_space_line(path: str | os.PathLike) -> str:
    """What a process says when a write under ``path`` found the disk full (one line)."""
    return f"no space left on {Path(path).absolute().parent} (writing {Path(path).name}); the last complete copy is kept"


def write_kept(path: str | os.PathLike, write: Callable[[BinaryIO], None], say: Callable[[str], None]) -> bool:
    """:func:`write_atomic`; a full disk is ``say(no_space_line(path))`` and False (the old file kept), any
    other error raises."""
    try:
        write_atomic(path, write)
    except OSError as exc:
        if not no_space(exc):
            raise
        say(no_space_line(path))
        return False
    return True

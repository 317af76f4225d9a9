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
    except BaseException:
        with suppress(OSError):
            tmp.unlink()
        raise


def write_atomic_text(path: str | os.PathLike, text: str) -> None:
    write_atomic(path, lambda f: f.write(text.encode()))


def no_space(exc: BaseException) -> bool:
    return isinstance(exc, OSError) and exc.errno in NO_SPACE


def no_space_line(path: str | os.PathLike) -> str:
    """What a process says when a write under ``path`` found the disk full (one line)."""
    return f"no space left on {Path(path).absolute().parent} (writing {Path(path).name}); the last complete copy is kept"

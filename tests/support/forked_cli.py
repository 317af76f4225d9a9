"""Run several `truav` commands from one interpreter: `truav.cli` is imported once, then each command runs
in a child forked from it, under its own address-space limit and time limit, with its own stdout and
stderr. What a command does is what `python -m truav.cli ...` does (the same ``main``, the same exit code,
a traceback printed as Python prints it), minus the interpreter start and imports each would pay again.

    python -m tests.support.forked_cli MEMORY_BYTES TIME_LIMIT_S PARALLEL [MODULE ...] < {"name": [argv...], ...}

prints {"name": [exit code, stdout, stderr], ...} as JSON. Each MODULE (one the commands import anyway when
they run: numba, zenoh, the recorder's readers) is imported once in the driver too, before any fork, so no
child spends its time importing it again (0.5-1 s each, most of a small command's time). The driver is
single-threaded when it forks (no Zenoh session, no parallel kernel has run in it), so each child starts as
a fresh process would.
"""

from __future__ import annotations

import importlib
import json
import os
import resource
import signal
import sys
import tempfile
import time
import traceback
from typing import Sequence


def _child(argv: list[str], out: int, err: int, memory: int) -> None:
    """In the forked child: never returns."""
    rc = 1
    try:
        os.dup2(out, 1)
        os.dup2(err, 2)
        devnull = os.open(os.devnull, os.O_RDONLY)
        os.dup2(devnull, 0)
        resource.setrlimit(resource.RLIMIT_AS, (memory, memory))
        from truav.cli.main import main
        rc = main(argv)
    except SystemExit as exc:
        rc = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except BaseException:  # what an uncaught exception prints in a fresh process
        traceback.print_exc()
        rc = 1
    finally:
        try:
            sys.stdout.flush()
            sys.stderr.flush()
        finally:
            os._exit(rc if isinstance(rc, int) and 0 <= rc < 256 else 1)


def run(commands: dict[str, list[str]], memory: int, time_limit_s: float, parallel: int,
        preload: Sequence[str] = ()) -> dict[str, list]:
    import truav.cli.main  # noqa: F401  (imported once, before any fork)
    for module in preload:
        importlib.import_module(module)
    sys.stdout.flush()
    sys.stderr.flush()
    pending = list(commands.items())
    running: dict[int, tuple[str, float, object, object]] = {}
    results: dict[str, list] = {}
    while pending or running:
        while pending and len(running) < parallel:
            name, argv = pending.pop(0)
            out, err = tempfile.TemporaryFile(), tempfile.TemporaryFile()
            pid = os.fork()
            if pid == 0:
                _child(argv, out.fileno(), err.fileno(), memory)
            running[pid] = (name, time.monotonic() + time_limit_s, out, err)
        pid, status = os.waitpid(-1, os.WNOHANG)
        if pid == 0:
            for child, (name, deadline, _, _) in running.items():
                if time.monotonic() > deadline:
                    os.kill(child, signal.SIGKILL)
            time.sleep(0.01)
            continue
        name, _, out, err = running.pop(pid)
        code = os.waitstatus_to_exitcode(status)
        texts = []
        for f in (out, err):
            f.seek(0)
            texts.append(f.read().decode(errors="replace"))
            f.close()
        if code == -signal.SIGKILL:
            texts[1] += f"\n(killed after {time_limit_s} s)"
        results[name] = [code, *texts]
    return results


if __name__ == "__main__":
    memory_bytes, limit_s, parallel_n = int(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3])
    print(json.dumps(run(json.load(sys.stdin), memory_bytes, limit_s, parallel_n, sys.argv[4:])))

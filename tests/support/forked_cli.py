"""Run several `truav` commands from one interpreter: `truav.cli` is imported once, then each command runs
in a child forked from it, under its own address-space limit and time limit, with its own stdout and
stderr. What a command does is what `python -m truav.cli ...` does (the same ``main``, the same exit code,
a traceback printed as Python prints it), minus the interpreter start and imports each would pay again.

    python -m tests.support.forked_cli MEMORY_BYTES TIME_LIMIT_S PARALLEL [MODULE ...]

reads batches of commands, one JSON line each ({"batch": n, "commands": {"name": [argv...], ...}}), and
answers each with one JSON line ({"batch": n, "results": {"name": [exit code, stdout, stderr], ...}}) until
its stdin ends (``Driver`` below starts one and keeps it for a module's tests: the interpreter and its imports
are paid once per module, not once per batch). Each MODULE (one the commands import anyway when they run:
numba, zenoh, the recorder's readers) is imported once in the driver too, before any fork, so no child spends
its time importing it again (0.5-1 s each, most of a small command's time). The driver is single-threaded when
it forks (no Zenoh session, no parallel kernel has run in it), so each child starts as a fresh process would.
"""

from __future__ import annotations

import importlib
import json
import os
import queue
import resource
import signal
import subprocess
import sys
import tempfile
import threading
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


def run(commands: dict[str, list[str]], memory: int, time_limit_s: float, parallel: int) -> dict[str, list]:
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


class Driver:
    """A driver process kept for many batches (the test's side): ``run`` sends one batch, returns its results.
    Each batch is numbered and its answer matched by number, so an answer left over from a test stopped while
    waiting (its timeout) is never read as the next test's; a driver that stopped answering is replaced."""

    def __init__(self, cwd, memory: int, time_limit_s: float, parallel: int, preload: Sequence[str] = ()) -> None:
        self._argv = [sys.executable, "-m", "tests.support.forked_cli", str(memory), str(time_limit_s), str(parallel),
                      *preload]
        self._cwd, self._time_limit_s, self._batch = cwd, time_limit_s, 0
        self._start()

    def _start(self) -> None:
        self._stderr = tempfile.TemporaryFile()
        self._proc = subprocess.Popen(self._argv, cwd=self._cwd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                      stderr=self._stderr, text=True)
        self._answers: queue.Queue = queue.Queue()
        threading.Thread(target=self._read, args=(self._proc, self._answers), daemon=True).start()

    @staticmethod
    def _read(proc: subprocess.Popen, answers: queue.Queue) -> None:
        for line in proc.stdout:
            answers.put(json.loads(line))
        answers.put(None)  # the driver ended

    def _stderr_text(self) -> str:
        self._stderr.seek(0)
        return self._stderr.read().decode(errors="replace")[-2000:]

    def run(self, commands: dict[str, list[str]]) -> dict[str, subprocess.CompletedProcess]:
        if self._proc.poll() is not None:
            self.close()
            self._start()
        self._batch += 1
        self._proc.stdin.write(json.dumps({"batch": self._batch, "commands": commands}) + "\n")
        self._proc.stdin.flush()
        # each command is killed after time_limit_s: the batch cannot take longer than all of them in turn
        deadline = time.monotonic() + self._time_limit_s * len(commands) + 60
        while True:
            try:
                answer = self._answers.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                why = f"the forking driver did not answer: {self._stderr_text()}"
                self.close()
                self._start()
                raise AssertionError(why) from None
            assert answer is not None, f"the forking driver ended: {self._stderr_text()}"
            if answer["batch"] == self._batch:  # not one left over from a batch whose test stopped waiting
                return {name: subprocess.CompletedProcess(commands[name], rc, out, err)
                        for name, (rc, out, err) in answer["results"].items()}

    def close(self) -> None:
        try:
            self._proc.stdin.close()  # its stdin ends: it exits
        except BrokenPipeError:  # it had ended
            pass
        try:
            self._proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        self._stderr.close()


def serve(memory: int, time_limit_s: float, parallel: int, preload: Sequence[str]) -> None:
    import truav.cli.main  # noqa: F401  (imported once, before any fork)
    for module in preload:
        importlib.import_module(module)
    for line in sys.stdin:
        if line.strip():
            batch = json.loads(line)
            results = run(batch["commands"], memory, time_limit_s, parallel)
            print(json.dumps({"batch": batch["batch"], "results": results}), flush=True)


if __name__ == "__main__":
    serve(int(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3]), sys.argv[4:])

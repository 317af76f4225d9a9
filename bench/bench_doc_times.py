"""The durations the README and the docs state, measured: each command whose comment says how long it takes
("about 55 s", "~1.5 min"), run as written at its full budget, in the reader's order, in one scratch directory.

    python bench/bench_doc_times.py                      # every stated command up to --max-s (15 min) stated
    python bench/bench_doc_times.py --only "truav train"  # some of them (their exact text, as on the page)
    python bench/bench_doc_times.py --list               # the stated times, not run

Prints, per command: the stated time, the measured wall time, the CPU seconds of its processes (user + sys,
children included) and the load average before and after, and exit 1 when one took more than twice what its
page states. A command stated longer than --max-s is not run: its page says how its time was extrapolated
(tests/docs/test_readme_commands.py, STATED_HOW, says which durations are checked how). Minutes of CPU per
command; run it on a quiet machine (the load average shows whether it was).
"""

from __future__ import annotations

import argparse
import os
import resource
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from tests.support.readme_commands import program, stated_times  # noqa: E402


def _cpu_children() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def measure(command: str, cwd: Path) -> tuple[int, float, float, str]:
    """(exit code, wall s, CPU s, load averages before -> after) of ``command`` run in ``cwd``."""
    load = os.getloadavg()
    cpu, began = _cpu_children(), time.monotonic()
    argv = program(shlex.split(command))
    assigned = shlex.split(command)[:-len(argv)]  # the page's VAR=value before the command
    env = {**os.environ, **{k: os.path.expanduser(v) for k, v in (a.split("=", 1) for a in assigned)}}
    with open(cwd / "bench-doc-times.log", "a") as log:
        log.write(f"\n$ {command}\n")
        log.flush()
        rc = subprocess.run(argv, cwd=cwd, env=env, stdin=subprocess.DEVNULL, stdout=log,
                            stderr=subprocess.STDOUT).returncode
    after = os.getloadavg()
    return rc, time.monotonic() - began, _cpu_children() - cpu, f"{load[0]:.1f} -> {after[0]:.1f}"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--only", nargs="+", metavar="COMMAND", help="only these commands (as the page writes them)")
    p.add_argument("--max-s", type=float, default=900, help="skip commands stated longer than this (default 900)")
    p.add_argument("--dir", help="scratch directory (default: a new temporary one; the repository's deploy/ and "
                                 "examples/ are linked into it, as a clone has them)")
    p.add_argument("--list", action="store_true", help="print the stated times and exit")
    args = p.parse_args(argv)
    stated = stated_times()
    if args.list:
        for command, seconds in stated.items():
            print(f"{seconds:8.0f} s  {command}")
        return 0
    unknown = [c for c in args.only or [] if c not in stated]
    if unknown:
        print(f"bench_doc_times: --only: no stated time for {unknown}", file=sys.stderr)
        return 2
    work = Path(args.dir or tempfile.mkdtemp(prefix="truav-doc-times-"))
    work.mkdir(parents=True, exist_ok=True)
    for folder in ("deploy", "examples"):  # what the commands name, as a clone has it
        if not (work / folder).exists():
            (work / folder).symlink_to(ROOT / folder)
    print(f"in {work} (log: bench-doc-times.log)", flush=True)
    slow = []
    for command, seconds in stated.items():
        if (args.only and command not in args.only) or (not args.only and seconds > args.max_s):
            continue
        rc, wall, cpu, load = measure(command, work)
        verdict = "ok" if wall <= 2 * seconds else "MORE THAN TWICE THE STATED TIME"
        if rc != 0:
            verdict = f"exit {rc}"
        if verdict != "ok":
            slow.append(command)
        print(f"stated {seconds:6.0f} s  measured {wall:7.1f} s  cpu {cpu:7.1f} s  load {load}  {verdict}  "
              f"{command}", flush=True)
    return 1 if slow else 0


if __name__ == "__main__":
    sys.exit(main())

"""CPU a swarm process spends starting: the working tree against a git revision, one process kind at a time.

    python bench/bench_startup.py                      # against HEAD, 5 runs each
    python bench/bench_startup.py --ref HEAD~3 --runs 7 --up

Each case runs as a fresh interpreter, in the working tree and in an extracted copy of ``--ref`` (git archive,
the index and working tree untouched), interleaved; a case's figure is the median over ``--runs`` of the
process's user+system CPU seconds (its own and its waited-for children's, from wait4). Cases: each part's
``--help`` (the import and parser cost every start pays); with ``--up``, a whole short ``truav-swarm up`` (5 UAVs,
1 episode of 5 steps: the supervisor, router, world and agent processes of a run, each importing and loading its
kernels), of the default scheme (agent:ppo-claim) and of --scheme truav. Prints old, new and new/old.
The kernels must be compiled already (any earlier run); the 1-minute load average is printed: figures taken
beside other jobs are noisier, the medians less so.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SWARM = [sys.executable, "-m", "truav.cli.swarm"]

def cases(with_up: bool, out: Path) -> dict[str, list[str]]:
    found = {f"{part} --help": [*SWARM, part, "--help"] for part in ("agent", "world", "controller", "router")}
    if with_up:
        for scheme in ("agent:ppo-claim", "truav"):
            found[f"up {scheme}"] = [*SWARM, "up", "--scheme", scheme, "--steps", "5", "--episodes", "1",
                                     "--no-plot", "--quiet", "--no-references", "--force", "--out", str(out / "up")]
    return found


def cpu_s(cmd: list[str], cwd: Path) -> float:
    env = dict(os.environ, PYTHONPATH=str(cwd))
    proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
    if proc.returncode != 0:
        raise SystemExit(f"bench_startup: {' '.join(cmd[:4])}... in {cwd} exited {proc.returncode}: {err[-400:]}")
    return usage.ru_utime + usage.ru_stime


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ref", default="HEAD", help="the revision to compare with (default HEAD)")
    ap.add_argument("--runs", type=int, default=5, help="runs per case and tree (default 5; the median is shown)")
    ap.add_argument("--up", action="store_true", help="also a whole short `truav-swarm up`")
    ap.add_argument("--only", help="run only the cases whose name contains this")
    args = ap.parse_args()
    if args.runs < 1:
        print("bench_startup: error: --runs must be at least 1", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="bench-startup-") as tmp:
        old = Path(tmp) / "old"
        old.mkdir()
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", args.ref], capture_output=True)
        if archive.returncode != 0:
            print(f"bench_startup: error: --ref {args.ref}: {archive.stderr.decode().strip()}", file=sys.stderr)
            return 2
        subprocess.run(["tar", "-x", "-C", str(old)], input=archive.stdout, check=True)
        print(f"load average {os.getloadavg()[0]:.2f}; old = {args.ref}, new = working tree; median of {args.runs} "
              f"runs, CPU s (user+sys)")
        print(f"{'case':28s} {'old':>7s} {'new':>7s} {'new/old':>8s}")
        for name, cmd in cases(args.up, Path(tmp)).items():
            if args.only and args.only not in name:
                continue
            for tree in (old, ROOT):  # one unmeasured run each: bytecode written, files in the page cache
                cpu_s(cmd, tree)
            runs: dict[Path, list[float]] = {old: [], ROOT: []}
            for _ in range(args.runs):
                for tree in (old, ROOT):
                    runs[tree].append(cpu_s(cmd, tree))
            o, n = statistics.median(runs[old]), statistics.median(runs[ROOT])
            print(f"{name:28s} {o:7.2f} {n:7.2f} {n / o:8.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

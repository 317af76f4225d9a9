"""CPU a swarm process spends starting: the working tree against a git revision, one process kind at a time.

    python bench/bench_startup.py                      # against HEAD, 5 runs each
    python bench/bench_startup.py --ref HEAD~3 --runs 7 --up

Each case runs as a fresh interpreter, in the working tree and in an extracted copy of ``--ref`` (git archive,
the index and working tree untouched), interleaved; a case's figure is the median over ``--runs`` of the
process's user+system CPU seconds (its own and its waited-for children's, from wait4). Cases: each part's
``--help`` (the import and parser cost every start pays); an agent process of --scheme truav and of the default
agent:ppo-claim from its start until it has joined (imports, checks, its kernels loaded, its session open; then
SIGTERM: the few milliseconds of its stop are counted too); a world process running 1 episode of 2 steps with no
agent (start, kernels, the steps, its stats; to a router the benchmark starts); with ``--up``, a whole short ``truav-swarm up`` (5 UAVs,
1 episode of 5 steps: the supervisor, router, world and agent processes of a run, each importing and loading its
kernels), of the default scheme (agent:ppo-claim) and of --scheme truav. Prints old, new and new/old.
The kernels must be compiled already (any earlier run); the 1-minute load average is printed: figures taken
beside other jobs are noisier, the medians less so.
"""

from __future__ import annotations

import argparse
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SWARM = [sys.executable, "-m", "truav.cli.swarm"]

def cases(with_up: bool, out: Path, endpoint: str) -> dict[str, tuple[list[str], str | None]]:
    """Each case's command and, for a process that runs until stopped, the line of its log after which it is
    stopped (SIGTERM); None: it ends by itself."""
    found: dict[str, tuple[list[str], str | None]] = {
        f"{part} --help": ([*SWARM, part, "--help"], None) for part in ("agent", "world", "controller", "router")}
    for scheme in ("truav", "agent:ppo-claim"):
        found[f"agent {scheme} to joined"] = ([*SWARM, "agent", "--id", "0", "--run", "bench-startup", "--scheme",
                                               scheme, "-e", endpoint], "joined run")
    found["world 2 steps"] = ([*SWARM, "world", "--run", "bench-startup-world", "-e", endpoint, "--episodes", "1",
                               "--set", "scenario.steps_per_episode=2", "--wait-agents", "0.2", "--max-missed", "1"],
                              None)
    if with_up:
        for scheme in ("agent:ppo-claim", "truav"):
            found[f"up {scheme}"] = ([*SWARM, "up", "--scheme", scheme, "--steps", "5", "--episodes", "1",
                                      "--no-plot", "--quiet", "--no-references", "--force", "--out",
                                      str(out / "up")], None)
    return found


def cpu_s(cmd: list[str], cwd: Path, stop_after: str | None = None) -> float:
    env = dict(os.environ, PYTHONPATH=str(cwd))
    proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    err = []
    if stop_after is not None:
        for line in proc.stderr:
            err.append(line)
            if stop_after in line:
                proc.send_signal(signal.SIGTERM)
                break
    err.extend(proc.stderr)
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    stopped = stop_after is not None and proc.returncode == 128 + signal.SIGTERM
    if proc.returncode != 0 and not stopped:
        raise SystemExit(f"bench_startup: {' '.join(cmd[:4])}... in {cwd} exited {proc.returncode}: "
                         f"{''.join(err)[-400:]}")
    return usage.ru_utime + usage.ru_stime


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def measure(found: dict[str, tuple[list[str], str | None]], args: argparse.Namespace, old: Path) -> None:
    """Print each case's median CPU in the old and the new tree, runs interleaved."""
    for name, (cmd, stop_after) in found.items():
        if args.only and args.only not in name:
            continue
        for tree in (old, ROOT):  # one unmeasured run each: bytecode written, files in the page cache
            cpu_s(cmd, tree, stop_after)
        runs: dict[Path, list[float]] = {old: [], ROOT: []}
        for _ in range(args.runs):
            for tree in (old, ROOT):
                runs[tree].append(cpu_s(cmd, tree, stop_after))
        o, n = statistics.median(runs[old]), statistics.median(runs[ROOT])
        print(f"{name:34s} {o:7.2f} {n:7.2f} {n / o:8.2f}", flush=True)


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
        print(f"{'case':34s} {'old':>7s} {'new':>7s} {'new/old':>8s}")
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        router = subprocess.Popen([*SWARM, "router", "-l", endpoint], cwd=ROOT, stdout=subprocess.DEVNULL,
                                  stderr=subprocess.DEVNULL)
        try:
            measure(cases(args.up, Path(tmp), endpoint), args, old)
        finally:
            router.terminate()
            router.wait(timeout=30)
    return 0


if __name__ == "__main__":
    sys.exit(main())

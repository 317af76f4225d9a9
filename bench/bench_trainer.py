"""Env-step throughput of the TRUAV trainer (world + every agent's action
selection and Q update), against the figures measured before the fused
kernel.

    python bench/bench_trainer.py            # batch 1, 10, 50 on one thread; steady state and start-up on all cores
    python bench/bench_trainer.py --full     # plus the paper's full run: 10 seeds x 5000 x 100 steps, all cores
    python bench/bench_trainer.py --agent truav   # TRUAV through the agent API against TRUAV's own trainer
    python bench/bench_trainer.py --agent bench.idle_agent:Idle   # the API's own price: a class doing nothing

--agent NAME times `truav train --agent NAME`'s trainer (agents.api_controller: the class's batched form
if it has one, else one call per UAV and step) against TRUAV's fused trainer, batch 10 on one thread,
the two alternated --repeats times (so they see the same load), and prints the ratio of the medians.

An env-step is one step of one environment (200 vehicles, 5 UAVs). Batch
figures run on one thread and time from the end of the first episode to the
end of the last (set-up excluded, every per-episode cost included). The
steady-state figure is the paper's 10-seed run on all cores: two runs of 50
and 250 episodes, their difference divided out, so start-up (imports, the
compiled-kernel cache, Q-table initialisation, warm-up traffic) cancels; the
start-up time is what is left. Each figure is the best of --repeats runs (the
machine may be shared: quote `uptime` with them).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from truav.analysis.trainer import run_chunk, run_parallel  # noqa: E402
from truav.cli.args import int_in  # noqa: E402
from truav.config import Config  # noqa: E402

BEFORE = {1: 10_700, 10: None, 50: 27_700, "steady": 44_000}
"""Measured at commit 0cd7060 (before the fused kernel) on the same 2-core
machine, as recorded in issue 15: batch 1 and 50 on one core, steady state
with 10 seeds on both cores (worker processes). Recorded constants, not
re-measured here; batch 10 was not recorded."""
BEFORE_FULL_RUN_S = 153.0
"""The README's paper-scale `truav train` at 0cd7060: 153 s (32,600 env-steps/s)."""


def batch_rate(batch: int, episodes: int, kind: str = "truav") -> float:
    from agents.fused import set_threads
    set_threads(1)
    cfg = Config().replace(learner={"episodes": episodes}, roads={"warmup_steps": 0})
    stamps: list[float] = []
    run_chunk(kind, cfg, list(range(batch)), episodes + 1,
              on_episode=lambda e, m: stamps.append(time.perf_counter()))
    return batch * episodes * cfg.scenario.steps_per_episode / (stamps[-1] - stamps[0])


def timed_run(episodes: int, workers: int) -> float:
    """Wall time of a fresh process training 10 seeds for `episodes` (start-up included)."""
    code = ("import time; t0 = time.perf_counter()\n"
            "from truav.config import Config\nfrom truav.analysis.trainer import run_parallel\n"
            f"run_parallel('truav', Config(), list(range(10)), {episodes}, workers={workers})\n"
            "print(time.perf_counter() - t0)")
    root = os.path.join(os.path.dirname(__file__), "..")
    out = subprocess.run([sys.executable, "-c", code], cwd=root, check=True, capture_output=True, text=True)
    return float(out.stdout.strip().splitlines()[-1])


AGENT_TRUAV_BEFORE = 0.041
"""`--agent truav` at 17fb350, before TruavAgent had a batched whole-episode form (its per-UAV form: one
Python call per UAV and step): 2,826 vs 69,232 env-steps/s, quiet machine. A recorded constant."""


def compare_agent(name: str, repeats: int, batch: int = 10, episodes: int = 20) -> None:
    import statistics
    from truav.analysis import agent_loader
    agent_loader.load(name, Config())
    kind = agent_loader.AGENT_KIND_PREFIX + name
    batch_rate(batch, 1), batch_rate(batch, 1, kind)  # compile and import once, outside the figures
    native, agent = [], []
    for _ in range(repeats):
        native.append(batch_rate(batch, episodes))
        agent.append(batch_rate(batch, episodes, kind))
    n, a = statistics.median(native), statistics.median(agent)
    print(f"batch {batch}, 1 thread, {episodes} episodes, median of {repeats} alternated runs:")
    print(f"  truav train (fused):   {n:9,.0f} env-steps/s  (runs: {', '.join(f'{r:,.0f}' for r in native)})")
    print(f"  --agent {name}: {a:9,.0f} env-steps/s  (runs: {', '.join(f'{r:,.0f}' for r in agent)})")
    before = f" (before, the per-UAV form: {AGENT_TRUAV_BEFORE})" if name == "truav" else ""
    print(f"  ratio: {a / n:.3f} of TRUAV's own trainer{before}")


def ratio(now: float, before: float | None) -> str:
    return f"x{now / before:.1f} vs {before:,} before" if before else "(no recorded before)"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--full", action="store_true", help="also time the paper's full 10-seed run")
    ap.add_argument("--workers", type=int_in(1), default=os.cpu_count() or 1,
                    help="worker processes, one kernel thread each (default: all cores)")
    ap.add_argument("--repeats", type=int_in(1), default=3, help="best of this many runs per figure (default 3)")
    ap.add_argument("--agent", metavar="NAME", help="compare an agent API class's trainer with TRUAV's (only that)")
    args = ap.parse_args()
    print(f"load: {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f} "
          f"on {os.cpu_count()} cores")
    if args.agent:
        compare_agent(args.agent, args.repeats)
        return
    for batch, episodes in ((1, 20), (10, 6), (50, 2)):
        rate = max(batch_rate(batch, episodes) for _ in range(args.repeats))
        print(f"batch {batch:3d}, 1 thread: {rate:9,.0f} env-steps/s  ({1e6 / rate:6.1f} us/env-step)  "
              f"{ratio(rate, BEFORE[batch])}")
    short, long_ = 50, 250
    t_short = min(timed_run(short, args.workers) for _ in range(args.repeats))
    t_long = min(timed_run(long_, args.workers) for _ in range(args.repeats))
    steady = 10 * (long_ - short) * 100 / (t_long - t_short)
    startup = t_short - 10 * short * 100 / steady
    print(f"steady state, 10 seeds in {args.workers} processes: {steady:9,.0f} env-steps/s  "
          f"{ratio(steady, BEFORE['steady'])}")
    print(f"start-up (fresh process, cached kernels): {startup:.1f} s")
    print(f"projected paper-scale run (10 x 5000 x 100): {startup + 5_000_000 / steady:.0f} s "
          f"(before: {BEFORE_FULL_RUN_S:.0f} s)")
    if args.full:
        cfg = Config()
        t0 = time.perf_counter()
        run_parallel("truav", cfg, list(range(10)), cfg.learner.episodes, workers=args.workers)
        elapsed = time.perf_counter() - t0
        n = 10 * cfg.learner.episodes * cfg.scenario.steps_per_episode
        print(f"full run: 10 seeds x {cfg.learner.episodes} episodes x {cfg.scenario.steps_per_episode} steps "
              f"in {args.workers} processes: {elapsed:.1f} s ({n / elapsed:,.0f} env-steps/s; "
              f"target < 60 s; before {BEFORE_FULL_RUN_S:.0f} s)")


if __name__ == "__main__":
    main()

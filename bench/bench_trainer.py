"""Env-step throughput of the TRUAV trainer (world + Q-learning), one process.

    python bench/bench_trainer.py            # batches 1, 10, 50
    python bench/bench_trainer.py --full     # plus the paper's full run: 10 seeds x 5000 x 100 steps, all cores

An env-step is one step of one environment (200 vehicles, 5 UAVs) including
every agent's action selection and Q update. Prints env-steps/s per batch size
and the batched/one-env ratio.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from truav.config import Config  # noqa: E402
from truav.trainer import run_chunk, run_parallel  # noqa: E402


def steps_per_second(batch: int, episodes: int) -> float:
    cfg = Config().replace(learner={"episodes": episodes}, roads={"warmup_steps": 0})
    # Time from the end of the first episode to the end of the last: excludes
    # set-up (Q-table init, spawn) but includes every per-episode cost.
    stamps: list[float] = []
    run_chunk("truav", cfg, list(range(batch)), episodes + 1,
              on_episode=lambda e, m: stamps.append(time.perf_counter()))
    elapsed = stamps[-1] - stamps[0]
    return batch * episodes * cfg.scenario.steps_per_episode / elapsed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--full", action="store_true", help="also time the paper's full 10-seed run")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    args = ap.parse_args()
    rates = {}
    for batch, episodes in ((1, 20), (10, 6), (50, 2)):
        rates[batch] = steps_per_second(batch, episodes)
        print(f"batch {batch:3d}: {rates[batch]:9,.0f} env-steps/s  ({1e6 / rates[batch]:6.1f} us/env-step)")
    print(f"batched/one-env ratio: x{rates[10] / rates[1]:.1f} (batch 10), x{rates[50] / rates[1]:.1f} (batch 50)")
    if args.full:
        cfg = Config()
        t0 = time.perf_counter()
        run_parallel("truav", cfg, list(range(10)), cfg.learner.episodes, workers=args.workers)
        elapsed = time.perf_counter() - t0
        n = 10 * cfg.learner.episodes * cfg.scenario.steps_per_episode
        print(f"full run: 10 seeds x {cfg.learner.episodes} episodes x {cfg.scenario.steps_per_episode} steps "
              f"on {args.workers} workers: {elapsed:.1f} s ({n / elapsed:,.0f} env-steps/s; target < 180 s)")


if __name__ == "__main__":
    main()

"""The variants tried for the learned policy (docs/results/learned-policy.md; needs the `marl` extra).

    python docs/scripts/ppo_search.py NAME '{"dagger_rounds": 3, "ppo_steps": 320000, "lr": 1e-4}' ...

Each NAME with its keyword arguments of truav.analysis.ppo_train.train (training seeds 0..15, --preset paper at
15 m/s, learner.sense_range_m = 1500) is trained, then flown greedy on held-out traffic (seeds 0..9 + EVAL_SEED_OFFSET,
20 episodes each, in the vector environment: the same actions as the agent API's evaluation, checked on the
shipped weights); prints its coverage with a 95% interval and its paired difference with the heuristic, and
appends one row per seed to OUT (default docs/figures/learned-policy-search.csv).
"""

from __future__ import annotations

import argparse
import csv
import json
import time
from pathlib import Path

import numpy as np
import torch

from ppo_train import config
from truav.analysis.ppo_train import export, greedy_coverage, train
from truav.analysis.trainer import run_chunk
from truav.seeding import EVAL_SEED_OFFSET
from truav.stats import effect_text, mean_ci, paired_effect

ENVS, SEEDS, EPISODES = 16, 10, 20


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("variants", nargs="+", help="NAME JSON pairs")
    ap.add_argument("--out", default="docs/figures/learned-policy-search.csv")
    args = ap.parse_args()
    torch.set_num_threads(1)
    cfg = config()
    seeds = [s + EVAL_SEED_OFFSET for s in range(SEEDS)]
    spread = np.nanmean(run_chunk("agent:spread", cfg, seeds, EPISODES, train=False).metrics["coverage_pct"], axis=0)
    out = Path(args.out)
    new = not out.exists()
    for name, spec in zip(args.variants[::2], args.variants[1::2]):
        kwargs = json.loads(spec)
        t = time.perf_counter()
        model, times = train(cfg, list(range(ENVS)), say=lambda line: None, **kwargs)
        cov = greedy_coverage(export(model, cfg, 4), cfg, seeds, EPISODES, 4)
        m, h = mean_ci(cov)
        print(f"{name} {spec}: {m:.1f} ± {h:.1f}%, minus spread "
              f"{effect_text(paired_effect(spread, cov), digits=1, noun='seeds')}; trained in "
              f"{times['total_s']:.0f} s ({time.perf_counter() - t:.0f} s with the evaluation)", flush=True)
        with open(out, "a", newline="") as f:
            w = csv.writer(f)
            if new:
                w.writerow(["variant", "settings", "seed", "coverage_pct", "spread_pct", "train_s"])
                new = False
            w.writerows([name, spec, s, f"{c:.4f}", f"{p:.4f}", f"{times['total_s']:.0f}"]
                         for s, (c, p) in enumerate(zip(cov, spread)))


if __name__ == "__main__":
    main()

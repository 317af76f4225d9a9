"""The variants tried for the learned policy (docs/results/learned-policy.md; needs the `marl` extra).

    python docs/scripts/ppo_search.py NAME '{"dagger_rounds": 3, "ppo_steps": 320000, "lr": 1e-4}' ...

Each NAME with its keyword arguments of truav.analysis.ppo_train.train (training seeds 0..15, --preset paper at
15 m/s, learner.sense_range_m = 1500) is trained, then flown greedy on held-out traffic (seeds 0..9 + EVAL_SEED_OFFSET,
20 episodes each, in the vector environment: the same actions as the agent API's evaluation, checked on the
shipped weights); prints its coverage with a 95% interval, its paired difference with the heuristic and how often
its action is the heuristic's on the states it visits (truav.analysis.ppo_train.agreement, training seeds, 2
episodes: over all and per decision kind), and appends one row per seed to OUT (default
docs/figures/learned-policy-search.csv).
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
from truav.analysis.ppo_train import KINDS, agreement, export, greedy_coverage, train
from truav.analysis.trainer import run_chunk
from truav.seeding import EVAL_SEED_OFFSET
from truav.stats import effect_text, mean_ci, paired_effect

ENVS, SEEDS, EPISODES = 16, 10, 20


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("variants", nargs="*", help="NAME JSON pairs")
    ap.add_argument("--out", default="docs/figures/learned-policy-search.csv")
    ap.add_argument("--figure", help="draw FIGURE.png from OUT (each variant's coverage, the heuristic's)")
    ap.add_argument("--pool", nargs="+", metavar="LABEL=NAME,NAME",
                    help="compare pools of OUT's variants (the training runs of one setting with different seeds): "
                         "each pool's per-seed mean over its runs, minus spread, and each pool minus the first")
    args = ap.parse_args()
    if args.figure:
        figure(Path(args.out), Path(args.figure))
        return
    if args.pool:
        pool(Path(args.out), args.pool)
        return
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
        arrays = export(model, cfg, 4, kwargs.get("memory", False))
        cov = greedy_coverage(arrays, cfg, seeds, EPISODES, 4)
        m, h = mean_ci(cov)
        agree = agreement(arrays, cfg, list(range(ENVS)), 2)
        print(f"{name} agreement with spread: {agree['all']:.3f}; " + ", ".join(
            f"{k} {agree[k]:.3f} ({100 * agree[k + '_share']:.0f}% of states)" for k in KINDS), flush=True)
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


def pool(table: Path, specs: list[str]) -> None:
    with open(table, newline="") as f:
        rows = list(csv.DictReader(f))
    runs = {}
    for r in rows:
        runs.setdefault(r["variant"], {})[int(r["seed"])] = (float(r["coverage_pct"]), float(r["spread_pct"]))
    pools = {}
    for spec in specs:
        label, names = spec.split("=", 1)
        per_run = [np.array([runs[n][s][0] for s in sorted(runs[n])]) for n in names.split(",")]
        spread = np.array([runs[names.split(",")[0]][s][1] for s in sorted(runs[names.split(",")[0]])])
        pools[label] = cov = np.mean(per_run, axis=0)
        m, h = mean_ci(cov)
        means = ", ".join(f"{c.mean():.1f}" for c in per_run)
        print(f"{label}: {m:.1f} ± {h:.1f}% (runs {means}); minus spread "
              f"{effect_text(paired_effect(spread, cov), digits=1, noun='seeds')}")
    first = next(iter(pools))
    for label, cov in list(pools.items())[1:]:
        print(f"{label} - {first}: {effect_text(paired_effect(pools[first], cov), digits=1, noun='seeds')}")


def figure(table: Path, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    with open(table, newline="") as f:
        rows = list(csv.DictReader(f))
    names = list(dict.fromkeys(r["variant"] for r in rows))
    cov = [np.array([float(r["coverage_pct"]) for r in rows if r["variant"] == n]) for n in names]
    spread = np.array([float(r["spread_pct"]) for r in rows if r["variant"] == names[0]])
    fig, ax = plt.subplots(figsize=(7.5, 1.6 + 0.35 * len(names)))
    stats = [mean_ci(c) for c in cov]
    ax.barh(range(len(names)), [m for m, _ in stats], xerr=[h for _, h in stats], color="C0", alpha=0.8, capsize=3)
    m, h = mean_ci(spread)
    ax.axvspan(m - h, m + h, color="C3", alpha=0.2, lw=0)
    ax.axvline(m, color="C3", label=f"heuristic spread {m:.1f}%")
    ax.axvline(60.0, color="k", ls="--", lw=1, label="target 60%")
    ax.set_yticks(range(len(names)), names, fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("coverage (%), greedy on held-out traffic")
    ax.set_xlim(0, 70)
    ax.grid(axis="x", alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title(f"--preset paper, 15 m/s: mean of {len(spread)} seeds x {EPISODES} episodes, 95% intervals",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()

"""Toward 60% coverage: the climbing heuristic (agents/claim_agent.py), its parts, and the heuristic `spread` at
several sensing ranges (docs/results/learned-policy.md, "Toward 60%").

    python docs/scripts/toward60.py --out docs/figures/toward60
    python docs/scripts/toward60.py --speed 5 --rows spread,claim --out docs/figures/toward60-5mps
    python docs/scripts/toward60.py --first-seed 10 --rows spread,claim --out docs/figures/toward60-seeds10-19

Under --preset paper at 15 m/s (--speed), each row (--rows: some of them) flies SEEDS seeds x EPISODES greedy episodes on held-out traffic (world
seed + EVAL_SEED_OFFSET, as `truav evaluate` does) in this process, through the agent API's controller. Prints the
page's Markdown table (means with 95% intervals over seeds; each row's difference from `spread` at 1500 m, paired on
the same seeds) and writes OUT.csv (one row per design and seed).
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

from agents.api_controller import ApiController
from agents.claim_agent import ClaimAgent, ClaimBatched
from agents.spread_agent import SpreadAgent
from truav.analysis.driver import run_episodes
from truav.config import Config
from truav.presets import preset_overrides
from truav.seeding import EVAL_SEED_OFFSET
from truav.stats import effect_text, mean_ci, paired_effect

SEEDS, EPISODES = 10, 20


def variant(name: str, climb: dict, spread: dict) -> type:
    """ClaimAgent with other constants (its batched form with the same)."""
    batched = type(name + "Batched", (ClaimBatched,), {"climb_params": climb, "spread_params": spread})
    return type(name, (ClaimAgent,), {"climb_params": climb, "spread_params": spread, "batched": batched})


ROWS = (  # (key, label, class, sensing range in m)
    ("spread", "spread (the bar)", SpreadAgent, 1500.0),
    ("spread_s1000", "spread, sensing 1000 m", SpreadAgent, 1000.0),
    ("spread_s2500", "spread, sensing 2500 m", SpreadAgent, 2500.0),
    ("spread_s5000", "spread, sensing 5000 m", SpreadAgent, 5000.0),
    ("climb", "spread + climb", variant("Climb", {"peer_sector_m": 0.0}, {}), 1500.0),
    ("climb_free", "spread + climb + peers' sectors left", variant("ClimbFree", {}, {}), 1500.0),
    ("climb_free_goal", "+ goal 500 m", variant("ClimbFreeGoal", {}, {"goal_ranges": 1.0}), 1500.0),
    ("claim", "claim: + push only within 500 m (the design)", ClaimAgent, 1500.0),
    ("claim_s1000", "claim, sensing 1000 m", ClaimAgent, 1000.0),
)


def measure(seeds: list[int], episodes: int, keys: set[str] | None = None, speed: float = 15.0) -> dict[str, np.ndarray]:
    """{row key: coverage % per seed, the mean over its episodes}."""
    base = Config().replace(**preset_overrides("paper")).replace(scenario={"uav_speed_mps": speed})
    held_out = [s + EVAL_SEED_OFFSET for s in seeds]
    out = {}
    for key, label, cls, sense in ROWS:
        if keys is not None and key not in keys:
            continue
        cfg = base.replace(learner={"sense_range_m": sense})
        got = run_episodes(cfg, held_out, ApiController(key, cls, cfg, held_out, train=False), episodes)
        out[key] = np.nanmean(got["coverage_pct"], axis=0)
        print(f"  {label}: {out[key].mean():.1f}%", flush=True)
    return out


def table(cov: dict[str, np.ndarray]) -> str:
    lines = ["| design (sensing 1500 m unless said) | coverage (%) | minus spread at 1500 m |", "|---|---|---|"]
    for key, label, _, _ in ROWS:
        if key not in cov:
            continue
        m, h = mean_ci(cov[key])
        diff = "" if key == "spread" else effect_text(paired_effect(cov["spread"], cov[key]), digits=1, noun="seeds")
        lines.append(f"| {label} | {m:.1f} ± {h:.1f} | {diff} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="docs/figures/toward60", help="OUT.csv (default %(default)s)")
    ap.add_argument("--seeds", type=int, default=SEEDS)
    ap.add_argument("--episodes", type=int, default=EPISODES)
    ap.add_argument("--first-seed", type=int, default=0, help="seeds FIRST_SEED.. (default %(default)s)")
    ap.add_argument("--speed", type=float, default=15.0, help="UAV speed in m/s (default %(default)s)")
    ap.add_argument("--rows", help="comma-separated row keys to fly (default: all; spread is always flown)")
    ap.add_argument("--replot", action="store_true", help="print the table from OUT.csv")
    args = ap.parse_args()
    known = [key for key, *_ in ROWS]
    keys = None if args.rows is None else {"spread", *args.rows.split(",")}
    if keys is not None and not keys <= set(known):
        ap.error(f"--rows: unknown {', '.join(sorted(keys - set(known)))} (known: {', '.join(known)})")
    out = Path(args.out).with_suffix(".csv")
    if args.replot:
        with open(out, newline="") as f:
            rows = list(csv.DictReader(f))
        print(table({k: np.array([float(r["coverage_pct"]) for r in rows if r["design"] == k])
                     for k in dict.fromkeys(r["design"] for r in rows)}))
        return
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    cov = measure(seeds, args.episodes, keys, args.speed)
    with open(out, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["design", "sense_range_m", "seed", "coverage_pct"])
        for key, _, _, sense in ROWS:
            if key not in cov:
                continue
            w.writerows([key, sense, seed, f"{v:.4f}"] for seed, v in zip(seeds, cov[key]))
    print(table(cov))


if __name__ == "__main__":
    main()

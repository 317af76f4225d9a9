"""The decentralized heuristic (agents/spread_agent.py) beside the patrol, hovering and random flight
(docs/results/heuristic.md).

    python docs/scripts/heuristic.py --out docs/figures/heuristic

Under --preset paper with the heuristic's sensing (learner.sense_range_m = SENSE_RANGE_M, which no other scheme
here reads), each scheme flies SEEDS seeds x EPISODES episodes on held-out traffic (world seed + EVAL_SEED_OFFSET,
as `truav evaluate` and the experiments' cells do) at every speed, in this process. Prints the page's Markdown
tables (means with 95% intervals over seeds; the heuristic's paired differences on the same seeds) and writes
OUT.csv (one row per scheme, speed and seed) and OUT.png.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np
import paired

from agents.spread_agent import with_sensing
from truav.analysis.trainer import run_chunk
from truav.config import Config
from truav.presets import preset_overrides
from truav.seeding import EVAL_SEED_OFFSET

SCHEMES = (("agent:spread", "spread (heuristic)"), ("patrol", "patrol"), ("hover", "hover"), ("random", "random"))
SPEEDS = (5.0, 10.0, 15.0, 20.0, 25.0)
SEEDS, EPISODES = 10, 20
STYLE = {"agent:spread": ("C3", "o", "-"), "patrol": ("C0", "s", "--"), "hover": ("C7", "^", ":"),
         "random": ("C2", "v", "-.")}


def measure(seeds: list[int], episodes: int) -> dict[tuple[str, float], np.ndarray]:
    """{(scheme, speed): coverage % per seed, the mean over its episodes}."""
    base = with_sensing("spread", Config().replace(**preset_overrides("paper")))
    out = {}
    for speed in SPEEDS:
        cfg = base.replace(scenario={"uav_speed_mps": speed})
        for kind, label in SCHEMES:
            result = run_chunk(kind, cfg, [s + EVAL_SEED_OFFSET for s in seeds], episodes, train=False)
            out[kind, speed] = np.nanmean(result.metrics["coverage_pct"], axis=0)
            print(f"  {label} at {speed:g} m/s: {out[kind, speed].mean():.1f}%", flush=True)
    return out


def tables(cov: dict[tuple[str, float], np.ndarray]) -> str:
    lines = paired.head("speed (m/s)", [label for _, label in SCHEMES])
    for speed in SPEEDS:
        lines.append(paired.row(f"{speed:g}", [paired.ci(cov[kind, speed]) for kind, _ in SCHEMES]))
    lines += ["", *paired.head("speed (m/s)", [f"spread - {label}" for _, label in SCHEMES[1:]])]
    for speed in SPEEDS:
        lines.append(paired.row(f"{speed:g}", [paired.diff(cov[kind, speed], cov["agent:spread", speed])
                                               for kind, _ in SCHEMES[1:]]))
    return "\n".join(lines)


def figure(cov: dict[tuple[str, float], np.ndarray], path: Path, n_seeds: int, episodes: int) -> None:
    paired.speed_figure(cov, list(SPEEDS), SCHEMES, STYLE, path,
                        f"Greedy on held-out traffic, --preset paper: mean of {n_seeds} seeds x {episodes} episodes, "
                        "95% bands", max(60.0, float(np.ceil(max(v.max() for v in cov.values()) / 10) * 10)) + 10.0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="docs/figures/heuristic", help="OUT.csv and OUT.png (default %(default)s)")
    ap.add_argument("--seeds", type=int, default=SEEDS)
    ap.add_argument("--episodes", type=int, default=EPISODES)
    ap.add_argument("--replot", action="store_true", help="redraw OUT.png and the tables from OUT.csv")
    args = ap.parse_args()
    out = Path(args.out)
    if args.replot:
        with open(out.with_suffix(".csv"), newline="") as f:
            rows = list(csv.DictReader(f))
        cov = {(k, s): np.array([float(r["coverage_pct"]) for r in rows if (r["scheme"], float(r["speed_mps"])) == (k, s)])
               for k, _ in SCHEMES for s in SPEEDS}
        figure(cov, out.with_suffix(".png"), len(cov[SCHEMES[0][0], SPEEDS[0]]), args.episodes)
        print(tables(cov))
        return
    cov = measure(list(range(args.seeds)), args.episodes)
    with open(out.with_suffix(".csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["scheme", "speed_mps", "seed", "coverage_pct"])
        for (kind, speed), values in cov.items():
            w.writerows([kind, speed, seed, f"{v:.4f}"] for seed, v in enumerate(values))
    figure(cov, out.with_suffix(".png"), args.seeds, args.episodes)
    print(tables(cov))


if __name__ == "__main__":
    main()

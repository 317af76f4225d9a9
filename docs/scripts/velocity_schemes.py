"""Coverage versus speed: TRUAV, the heuristic, the learned policy and the patrol, paired on the same seeds
(docs/results/velocity.md).

    python docs/scripts/velocity_schemes.py RUN --out docs/figures/velocity-schemes

RUN is a `truav experiment velocity --schemes truav ppo spread patrol` run (the page gives the command). Reads
its finished cells' greedy evaluation (held-out traffic), writes OUT.csv (one row per scheme, speed and seed: the
mean coverage over the evaluation episodes) and OUT.png (coverage against speed, 95% bands), and prints the
page's tables: means with 95% intervals over seeds, then ppo's paired differences on the same seeds.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

from truav.stats import effect_text, mean_ci, paired_effect

SCHEMES = (("truav", "TRUAV (Q-learning)"), ("spread", "spread (heuristic)"), ("ppo", "ppo (learned)"),
           ("patrol", "patrol"))
STYLE = {"truav": ("C0", "s", "-"), "spread": ("C1", "o", "--"), "ppo": ("C2", "D", "-"), "patrol": ("C3", "^", ":")}


def per_seed(run: Path) -> dict[tuple[str, float], dict[int, float]]:
    """{(scheme, speed): {seed: mean coverage over the evaluation episodes}} of a run's finished cells."""
    out: dict[tuple[str, float], dict[int, float]] = {}
    for f in sorted((run / "cells").glob("*.npz")):
        scheme, rest = f.stem.split("_v", 1)
        speed = float(rest.split("_", 1)[0])
        with np.load(f) as d:
            values = np.nanmean(d["eval/coverage_pct"], axis=0)
            out.setdefault((scheme, speed), {}).update(zip((int(s) for s in d["seeds"]), values.tolist()))
    return out


def arrays(cov: dict[tuple[str, float], dict[int, float]]) -> tuple[list[float], dict[tuple[str, float], np.ndarray]]:
    speeds = sorted({s for _, s in cov})
    seeds = sorted(cov[SCHEMES[0][0], speeds[0]])
    return speeds, {k: np.array([v[s] for s in seeds]) for k, v in cov.items()}


def tables(cov: dict[tuple[str, float], dict[int, float]]) -> str:
    speeds, a = arrays(cov)
    lines = ["| speed (m/s) | " + " | ".join(label for _, label in SCHEMES) + " |", "|---" * (len(SCHEMES) + 1) + "|"]
    for v in speeds:
        lines.append(f"| {v:g} | " + " | ".join("{:.1f} ± {:.1f}".format(*mean_ci(a[k, v])) for k, _ in SCHEMES) + " |")
    others = [(k, label) for k, label in SCHEMES if k != "ppo"]
    lines += ["", "| speed (m/s) | " + " | ".join(f"ppo - {k}" for k, _ in others) + " | spread - truav |",
              "|---" * (len(others) + 2) + "|"]
    for v in speeds:
        cells = [effect_text(paired_effect(a[k, v], a["ppo", v]), digits=1, noun="seeds") for k, _ in others]
        cells.append(effect_text(paired_effect(a["truav", v], a["spread", v]), digits=1, noun="seeds"))
        lines.append(f"| {v:g} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def figure(cov: dict[tuple[str, float], dict[int, float]], path: Path, title: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    speeds, a = arrays(cov)
    fig, ax = plt.subplots(figsize=(7, 4.2))
    x = np.array(speeds)
    for k, label in SCHEMES:
        colour, marker, ls = STYLE[k]
        m, h = (np.array(t) for t in zip(*(mean_ci(a[k, v]) for v in speeds)))
        ax.fill_between(x, m - h, m + h, color=colour, alpha=0.15, lw=0)
        ax.plot(x, m, color=colour, marker=marker, ls=ls, label=label)
    ax.axvline(15, color="k", lw=0.6, alpha=0.4)
    ax.text(15.3, 2, "ppo trained at 15 m/s", fontsize=7, alpha=0.7)
    ax.set_xlabel("UAV speed (m/s)")
    ax.set_ylabel("coverage (%)")
    ax.set_xticks(x)
    ax.set_ylim(0, 70)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper center", ncol=len(SCHEMES), fontsize=8)
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run", nargs="?", help="the velocity run (omit with --replot)")
    ap.add_argument("--out", default="docs/figures/velocity-schemes", help="OUT.csv and OUT.png (default %(default)s)")
    ap.add_argument("--title", default="--preset paper, sensing 1500 m: greedy, 10 seeds x 20 held-out episodes, 95% "
                                       "bands\nTRUAV trained 500 episodes per speed; ppo trained at 15 m/s only")
    ap.add_argument("--replot", action="store_true", help="redraw OUT.png and the tables from OUT.csv")
    args = ap.parse_args()
    out = Path(args.out)
    if args.replot:
        cov: dict[tuple[str, float], dict[int, float]] = {}
        with open(out.with_suffix(".csv"), newline="") as f:
            for r in csv.DictReader(f):
                cov.setdefault((r["scheme"], float(r["speed_mps"])), {})[int(r["seed"])] = float(r["coverage_pct"])
    else:
        if not args.run:
            ap.error("RUN is required (or --replot)")
        cov = per_seed(Path(args.run))
        with open(out.with_suffix(".csv"), "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["scheme", "speed_mps", "seed", "coverage_pct"])
            for (k, v), values in sorted(cov.items()):
                w.writerows([k, v, s, f"{c:.4f}"] for s, c in sorted(values.items()))
    figure(cov, out.with_suffix(".png"), args.title)
    print(tables(cov))


if __name__ == "__main__":
    main()

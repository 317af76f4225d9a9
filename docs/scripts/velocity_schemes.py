"""Coverage versus speed: TRUAV, the heuristic, the learned policy and the patrol, paired on the same seeds
(docs/results/velocity.md).

    python docs/scripts/velocity_schemes.py RUN --out docs/figures/velocity-schemes

    python docs/scripts/velocity_schemes.py RUN2 --merge --out docs/figures/velocity-schemes

RUN is a `truav experiment velocity --schemes truav ppo spread patrol` run (the page gives the command). Reads
its finished cells' greedy evaluation (held-out traffic), writes OUT.csv (one row per scheme, speed and seed: the
mean coverage over the evaluation episodes) and OUT.png (coverage against speed, 95% bands), and prints the
page's tables: means with 95% intervals over seeds, then the paired differences on the same seeds.
With --merge, RUN2's cells (e.g. `--schemes claim agents.ppo_agent:PpoClaimAgent`, same seeds and evaluation)
are added to OUT.csv's rows; a scheme, speed and seed in both must agree (that checks the pairing).
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np
import paired


SCHEMES = (("truav", "TRUAV (Q-learning)"), ("spread", "spread (heuristic)"), ("ppo", "ppo (learned)"),
           ("patrol", "patrol"), ("claim", "claim (heuristic)"), ("ppo-claim", "ppo-claim (learned clone)"),
           ("ppo-disc", "ppo-disc (learned, senses the disc)"))
STYLE = {"truav": ("C0", "s", "-"), "spread": ("C1", "o", "--"), "ppo": ("C2", "D", "-"), "patrol": ("C3", "^", ":"),
         "claim": ("C4", "v", "--"), "ppo-claim": ("C5", "P", "-"), "ppo-disc": ("C6", "X", "-")}
# a cell's file name spells a class-path scheme with "-" for ":"; the page calls it by its registered name
ALIASES = {"agents.ppo_agent-PpoClaimAgent": "ppo-claim", "agents.ppo_agent-PpoDiscAgent": "ppo-disc"}


def per_seed(run: Path) -> dict[tuple[str, float], dict[int, float]]:
    """{(scheme, speed): {seed: mean coverage over the evaluation episodes}} of a run's finished cells."""
    out: dict[tuple[str, float], dict[int, float]] = {}
    for f in sorted((run / "cells").glob("*.npz")):
        scheme, rest = f.stem.split("_v", 1)
        scheme = ALIASES.get(scheme, scheme)
        speed = float(rest.split("_", 1)[0])
        with np.load(f) as d:
            values = np.nanmean(d["eval/coverage_pct"], axis=0)
            out.setdefault((scheme, speed), {}).update(zip((int(s) for s in d["seeds"]), values.tolist()))
    return out


def arrays(cov: dict[tuple[str, float], dict[int, float]]) -> tuple[list[float], dict[tuple[str, float], np.ndarray]]:
    speeds = sorted({s for _, s in cov})
    seeds = sorted(cov[SCHEMES[0][0], speeds[0]])
    return speeds, {k: np.array([v[s] for s in seeds]) for k, v in cov.items()}


def _differences(a: dict[tuple[str, float], np.ndarray], speeds: list[float],
                 pairs: tuple[tuple[str, str], ...]) -> list[str]:
    """A table of "x - y" per speed for each (x, y) of ``pairs``, paired on the seeds."""
    lines = paired.head("speed (m/s)", [f"{x} - {y}" for x, y in pairs])
    for v in speeds:
        lines.append(paired.row(f"{v:g}", [paired.diff(a[y, v], a[x, v]) for x, y in pairs]))
    return lines


def tables(cov: dict[tuple[str, float], dict[int, float]]) -> str:
    speeds, a = arrays(cov)
    shown = [(k, label) for k, label in SCHEMES if (k, speeds[0]) in a]
    lines = paired.head("speed (m/s)", [label for _, label in shown])
    for v in speeds:
        lines.append(paired.row(f"{v:g}", [paired.ci(a[k, v]) for k, _ in shown]))
    others = [(k, label) for k, label in SCHEMES if k in ("truav", "spread", "patrol")]
    lines += ["", *paired.head("speed (m/s)", [*(f"ppo - {k}" for k, _ in others), "spread - truav"])]
    for v in speeds:
        cells = [paired.diff(a[k, v], a["ppo", v]) for k, _ in others]
        cells.append(paired.diff(a["truav", v], a["spread", v]))
        lines.append(paired.row(f"{v:g}", cells))
    for pairs in ((("ppo-claim", "spread"), ("ppo-claim", "claim"), ("claim", "spread")),
                  (("ppo-disc", "spread"), ("ppo-disc", "claim"), ("ppo-disc", "ppo-claim"))):
        if all((k, speeds[0]) in a for pair in pairs for k in pair):
            lines += ["", *_differences(a, speeds, pairs)]
    return "\n".join(lines)


def read_csv(path: Path) -> dict[tuple[str, float], dict[int, float]]:
    cov: dict[tuple[str, float], dict[int, float]] = {}
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            cov.setdefault((r["scheme"], float(r["speed_mps"])), {})[int(r["seed"])] = float(r["coverage_pct"])
    return cov


def merge(cov: dict[tuple[str, float], dict[int, float]], new: dict[tuple[str, float], dict[int, float]]) -> str:
    """Adds ``new`` to ``cov``; returns the first (scheme, speed, seed) in both whose values differ, else ""."""
    for k, values in new.items():
        for s, c in values.items():
            if s in cov.get(k, {}) and abs(cov[k][s] - c) > 1e-4:
                return f"{k[0]} {k[1]:g} m/s seed {s}: {cov[k][s]:.4f} in the CSV, {c:.4f} in the run"
        cov.setdefault(k, {}).update(values)
    return ""


def _trained_at_15(ax) -> None:
    ax.axvline(15, color="k", lw=0.6, alpha=0.4)
    ax.text(15.3, 2, "ppo, ppo-claim trained at 15 m/s", fontsize=7, alpha=0.7)
    ax.axvline(5, color="k", lw=0.6, alpha=0.4)
    ax.text(5.3, 6, "ppo-disc's own network trained at 5 m/s\n(from 10 m/s it flies ppo-claim's)", fontsize=7, alpha=0.7)


def figure(cov: dict[tuple[str, float], dict[int, float]], path: Path, title: str) -> None:
    speeds, a = arrays(cov)
    schemes = [(k, label) for k, label in SCHEMES if (k, speeds[0]) in a]
    paired.speed_figure(a, speeds, schemes, STYLE, path, title, 100 if len(schemes) > 4 else 70,
                        mark=_trained_at_15, legend_cols=3)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run", nargs="?", help="the velocity run (omit with --replot)")
    ap.add_argument("--out", default="docs/figures/velocity-schemes", help="OUT.csv and OUT.png (default %(default)s)")
    ap.add_argument("--title", default="--preset paper, sensing 1500 m: greedy, 10 seeds x 20 held-out episodes, 95% "
                                       "bands\nTRUAV trained 500 episodes per speed; ppo, ppo-claim at 15 m/s only; ppo-disc (below)")
    ap.add_argument("--replot", action="store_true", help="redraw OUT.png and the tables from OUT.csv")
    ap.add_argument("--merge", action="store_true", help="add RUN's cells to OUT.csv's rows (same seeds)")
    args = ap.parse_args()
    out = Path(args.out)
    if args.replot:
        cov = read_csv(out.with_suffix(".csv"))
    else:
        if not args.run:
            ap.error("RUN is required (or --replot)")
        if args.merge:
            cov = read_csv(out.with_suffix(".csv"))
            clash = merge(cov, per_seed(Path(args.run)))
            if clash:
                ap.error(f"RUN is not paired with {out.with_suffix('.csv')}: {clash}")
        else:
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

"""The deep decentralized learner (agents.deep_iql) at the paper's budget, beside TRUAV and the patrol
(docs/results/deep-learner.md).

    python docs/scripts/deep_learner.py RUN --sac RUN_SAC --oracles docs/figures/oracle_ceiling_paper*.json \
        --out docs/figures/deep-learner

RUN is a `truav experiment velocity` run with the schemes agents.deep_iql:DeepIql, truav and patrol (the
page gives the command); RUN_SAC one holding central cells (drawn and tabled where they exist, unpaired:
another run). Prints the page's Markdown tables (greedy evaluation on held-out traffic: means with 95%
intervals over seeds; paired differences on the same seeds; the training curves by window of 500 episodes,
with the paired change over the last 1000 episodes) and draws OUT.png.
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import numpy as np

from truav.stats import effect_text, mean_ci, paired_effect

DEEP = "agents.deep_iql-DeepIql"  # the scheme agents.deep_iql:DeepIql as its cells are named
SCHEMES = ((DEEP, "deep IQL"), ("truav", "TRUAV (best state design)"), ("patrol", "patrol"), ("central", "SAC"))
METRICS = (("coverage_pct", "coverage (%)", 1.0, 1), ("pdr", "PDR (%)", 100.0, 1), ("delay_ms", "delay (ms)", 1.0, 0),
           ("energy_j", "energy (kJ/UAV)", 1e-3, 2))
CELL = re.compile(r"^(?P<scheme>.+)_v(?P<speed>[0-9.]+)_u")
WINDOW = 500
GOAL = 60.0
SPEED_COLOUR = {5.0: "#7b3294", 10.0: "#2c7bb6", 15.0: "#1a9641", 20.0: "#fdae61", 25.0: "#d7191c"}


def read_cells(run: Path) -> dict[str, dict[float, dict[str, dict[int, np.ndarray]]]]:
    """{scheme: {speed: {"eval/<metric>" | "train/<metric>": {seed: per-episode values}}}} of a run's cells."""
    out: dict = {}
    for f in sorted((run / "cells").glob("*.npz")):
        m = CELL.match(f.stem)
        if not m:
            continue
        with np.load(f) as d:
            seeds = [int(s) for s in d["seeds"]]
            into = out.setdefault(m["scheme"], {}).setdefault(float(m["speed"]), {})
            for key in d.files:
                if key.startswith(("eval/", "train/")):
                    into.setdefault(key, {}).update({s: d[key][:, i] for i, s in enumerate(seeds)})
    return out


def per_seed(cells, scheme, speed, key, scale=1.0) -> dict[int, float]:
    got = cells.get(scheme, {}).get(speed, {}).get(f"eval/{key}", {})
    return {s: float(np.nanmean(v)) * scale for s, v in got.items()}


def ci_text(values: dict[int, float], digits: int) -> str:
    m, h = mean_ci(np.array(list(values.values())), axis=0)
    return f"{float(m):.{digits}f} ± {float(h):.{digits}f}"


def paired(a: dict[int, float], b: dict[int, float]):
    seeds = sorted(set(a) & set(b))
    return paired_effect([a[s] for s in seeds], [b[s] for s in seeds])


def tables(cells, sac, oracles) -> None:
    speeds = sorted({v for per in cells.values() for v in per})
    print("| speed m/s | scheme | seeds | " + " | ".join(label for _, label, _, _ in METRICS) + " |")
    print("|---|---|---|" + "---|" * len(METRICS))
    for v in speeds:
        for scheme, label in SCHEMES:
            src = sac if scheme == "central" else cells
            if v not in src.get(scheme, {}):
                continue
            cols = [ci_text(per_seed(src, scheme, v, k, s), d) for k, _, s, d in METRICS]
            n = len(per_seed(src, scheme, v, "coverage_pct"))
            print(f"| {v:g} | {label} | {n} | " + " | ".join(cols) + " |")
        if v in oracles:
            print(f"| {v:g} | speed-limited oracle | {oracles[v]['seeds']} | {oracles[v]['reachable']['mean']:.1f} | | | |")
    print("\n| speed m/s | paired on the same seeds | " + " | ".join(label for _, label, _, _ in METRICS) + " |")
    print("|---|---|" + "---|" * len(METRICS))
    for v in speeds:
        for other, label in (("truav", "deep IQL minus TRUAV"), ("patrol", "deep IQL minus patrol")):
            if other not in cells or v not in cells[other] or v not in cells.get(DEEP, {}):
                continue
            cols = [effect_text(paired(per_seed(cells, other, v, k, s), per_seed(cells, DEEP, v, k, s)),
                                digits=d, noun="seeds") for k, _, s, d in METRICS]
            print(f"| {v:g} | {label} | " + " | ".join(cols) + " |")


def curves(cells) -> None:
    """Training coverage and reward by window (mean over seeds), and the paired change of the last 1000 episodes."""
    print(f"\n| speed m/s | scheme | training coverage % by window of {WINDOW} episodes | reward, first and last window "
          f"| last {WINDOW} minus the {WINDOW} before, coverage points (paired) "
          f"| greedy evaluation minus the last {WINDOW} training episodes, points (paired) |")
    print("|---|---|---|---|---|---|")
    for v in sorted(cells.get(DEEP, {})):
        for scheme, label in SCHEMES[:2]:
            got = cells.get(scheme, {}).get(v, {})
            if "train/coverage_pct" not in got:
                continue
            cov = np.stack([got["train/coverage_pct"][s] for s in sorted(got["train/coverage_pct"])])
            rew = np.stack([got["train/reward"][s] for s in sorted(got["train/reward"])])
            w = cov.shape[1] // WINDOW
            by = cov[:, :w * WINDOW].reshape(len(cov), w, WINDOW).mean(axis=2)
            rw = rew[:, :w * WINDOW].reshape(len(rew), w, WINDOW).mean(axis=2).mean(axis=0)
            change = effect_text(paired_effect(by[:, -2], by[:, -1]), digits=1, noun="seeds") if w >= 2 else ""
            greedy = per_seed(cells, scheme, v, "coverage_pct")
            to_greedy = effect_text(paired_effect(by[:, -1], [greedy[s] for s in sorted(greedy)]), digits=1,
                                    noun="seeds")
            print(f"| {v:g} | {label} | " + " ".join(f"{x:.1f}" for x in by.mean(axis=0)) +
                  f" | {rw[0]:.3f} → {rw[-1]:.3f} | {change} | {to_greedy} |")


def figure(cells, sac, oracles, out: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(13, 5.2))
    style = {DEEP: ("C3", "s"), "truav": ("C0", "o"), "patrol": ("C7", "^"), "central": ("C1", "D")}
    for scheme, label in SCHEMES:
        src = sac if scheme == "central" else cells
        speeds = sorted(src.get(scheme, {}))
        if not speeds:
            continue
        stats = [mean_ci(np.array(list(per_seed(src, scheme, v, "coverage_pct").values())), axis=0) for v in speeds]
        m, h = np.array([float(s[0]) for s in stats]), np.array([float(s[1]) for s in stats])
        colour, marker = style[scheme]
        ax.errorbar(speeds, m, yerr=h, color=colour, marker=marker, capsize=4, label=label)
    if oracles:
        vs = sorted(oracles)
        ax.plot(vs, [oracles[v]["reachable"]["mean"] for v in vs], "k--", marker="x", label="oracle: speed-limited chaser")
    ax.axhline(GOAL, color="grey", lw=1, ls="-.", label="the project's goal (60%)")
    ax.set(xlabel="UAV speed (m/s)", ylabel="greedy coverage on held-out traffic (%)", ylim=(0, 100),
           title="Greedy evaluation, mean of 10 seeds, 95% intervals")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize=8, ncol=2)
    for scheme, label in SCHEMES[:2]:  # each speed's two curves in one colour: deep solid, TRUAV dotted
        for v in sorted(cells.get(DEEP, {})):
            got = cells.get(scheme, {}).get(v, {}).get("train/coverage_pct")
            if not got:
                continue
            cov = np.stack([got[s] for s in sorted(got)]).mean(axis=0)
            smooth = np.convolve(cov, np.ones(100) / 100, mode="valid")
            kind = "-" if scheme == DEEP else ":"
            bx.plot(np.arange(len(smooth)) + 100, smooth, kind, color=SPEED_COLOUR.get(v, "k"),
                    label=f"{label}, {v:g} m/s")
    bx.set(xlabel="training episode", ylabel="training coverage (%), 100-episode mean over seeds",
           title="Training curves (exploring: epsilon 1 → 0.05 by episode 4000)", ylim=(0, 60))
    bx.grid(alpha=0.3)
    bx.legend(fontsize=7, ncol=2, loc="upper left")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out.with_suffix(".png"), dpi=110)
    print(f"\nwrote {out.with_suffix('.png')}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path, help="the velocity run with the deep learner, truav and patrol")
    ap.add_argument("--sac", type=Path, help="a velocity run holding central cells (unpaired reference)")
    ap.add_argument("--oracles", nargs="*", default=[], help="docs/scripts/oracle_ceiling.py JSON files")
    ap.add_argument("--out", type=Path, default=Path("docs/figures/deep-learner"), help="figure path (no suffix)")
    a = ap.parse_args()
    cells = read_cells(a.run)
    sac = read_cells(a.sac) if a.sac else {}
    oracles = {float(d["speed_mps"]): d for d in (json.loads(Path(f).read_text()) for f in a.oracles)}
    tables(cells, sac, oracles)
    curves(cells)
    figure(cells, sac, oracles, a.out)


if __name__ == "__main__":
    main()

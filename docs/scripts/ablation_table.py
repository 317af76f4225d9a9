"""Markdown table of finished experiment cells (issue 16's ablation and SAC sweep).

    python docs/scripts/ablation_table.py runs/ablation/base runs/ablation/sense1500 ...

One row per run directory (each holding one scheme at one speed, any number of
cells): the greedy evaluation (mean over seeds of each seed's mean, 95%
Student-t half-width over seeds, as `summary.md`), the last training window's
coverage, and for TRUAV the states each agent updated in at least once.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from truav.stats import mean_ci

WINDOW = int(__import__("os").environ.get("WINDOW", 200))
"""Episodes of the last training window (env WINDOW)."""


def load(run: Path) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, list[float]]]:
    train: dict[str, list[np.ndarray]] = {}
    ev: dict[str, list[np.ndarray]] = {}
    meta: dict[str, list[float]] = {}
    for f in sorted((run / "cells").glob("*.npz")):
        with np.load(f) as d:
            for k in d.files:
                if k.startswith("train/"):
                    train.setdefault(k[6:], []).append(d[k])
                elif k.startswith("eval/"):
                    ev.setdefault(k[5:], []).append(d[k])
                elif k.startswith("meta/"):
                    meta.setdefault(k[5:], []).append(float(d[k]))
    return ({k: np.concatenate(v, axis=1) for k, v in train.items()},
            {k: np.concatenate(v, axis=1) for k, v in ev.items()}, meta)


def cell(values: np.ndarray, scale: float = 1.0, digits: int = 1) -> str:
    m, h = mean_ci(np.nanmean(values, axis=0) * scale)
    return f"{m:.{digits}f} ± {h:.{digits}f}"


def main(runs: list[str]) -> None:
    print("| run | seeds | coverage % | PDR % | delay ms | above hover kJ/UAV | last training window coverage % "
          "| states visited per agent (of) | train s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in runs:
        train, ev, meta = load(Path(r))
        if not ev:
            continue  # not finished
        n_seeds = ev["coverage_pct"].shape[1]
        last = np.mean(train["coverage_pct"][-min(WINDOW, len(train["coverage_pct"])):])
        if "states_visited_mean" in meta:
            visited = (f"{np.mean(meta['states_visited_mean']):.0f} ({min(meta['states_visited_min']):.0f}-"
                       f"{max(meta['states_visited_max']):.0f}) of {meta['n_states'][0]:.0f}")
        else:
            visited = ""
        print(f"| {Path(r).name} | {n_seeds} | {cell(ev['coverage_pct'])} | {cell(ev['pdr'], 100)} "
              f"| {cell(ev['delay_ms'])} | {cell(ev['energy_above_hover_j'], 1e-3, 2)} | {last:.1f} | {visited} "
              f"| {sum(meta['train_s']):.0f} |")


if __name__ == "__main__":
    main(sys.argv[1:])

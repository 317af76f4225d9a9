"""Paired comparison of designs on the same seeds (issue 32's ablation).

    python docs/scripts/paired_designs.py runs/abl3/paper_best runs/abl3/paper_diff ...

The first run is the reference; for each other run, per speed and seed, the difference of the greedy
evaluation's coverage (mean over the evaluation episodes) from the reference's on the same speed and
seed, then the mean ± 95% Student-t interval of those differences over the seeds (a row per speed).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from truav.stats import mean_ci


def per_seed(run: Path, key: str = "coverage_pct") -> dict[tuple[float, int], float]:
    """{(speed, seed): mean over evaluation episodes} of every finished cell of ``run``."""
    out: dict[tuple[float, int], float] = {}
    for f in sorted((run / "cells").glob("*.npz")):
        speed = float(next(p for p in f.stem.split("_") if p.startswith("v"))[1:])
        with np.load(f) as d:
            seeds = [int(s) for s in d["meta/seeds"]] if "meta/seeds" in d.files else None
            values = np.nanmean(d[f"eval/{key}"], axis=0)
        if seeds is None:  # the cell file name holds the seed range: ..._s<first>-<last>_...
            part = next(p for p in f.stem.split("_") if p.startswith("s") and "-" in p)
            first, last = (int(x) for x in part[1:].split("-"))
            seeds = list(range(first, last + 1))
        out.update(zip([(speed, s) for s in seeds], values.tolist()))
    return out


def main(runs: list[str]) -> None:
    ref = per_seed(Path(runs[0]))
    print(f"| design | speed m/s | seeds | coverage % | minus {Path(runs[0]).name}, paired, points | better on seeds |")
    print("|---|---|---|---|---|---|")
    for r in runs:
        got = per_seed(Path(r))
        for speed in sorted({v for v, _ in got}):
            seeds = sorted(s for v, s in set(ref) & set(got) if v == speed)
            if not seeds:
                continue
            diff = np.array([got[speed, s] - ref[speed, s] for s in seeds])
            m, h = mean_ci(np.array([got[speed, s] for s in seeds]))
            dm, dh = mean_ci(diff)
            print(f"| {Path(r).name} | {speed:g} | {len(seeds)} | {m:.1f} ± {h:.1f} | {dm:+.1f} ± {dh:.1f} "
                  f"| {int(np.sum(diff > 0))} of {len(seeds)} |")


if __name__ == "__main__":
    main(sys.argv[1:])

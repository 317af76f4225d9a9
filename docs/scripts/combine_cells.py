"""Write the velocity experiment's tables and figures from finished cell files
of several invocations whose configs differ in sections one scheme does not
read (here: TRUAV's state design, which the SAC and the patrol ignore; a
cell's key hashes every section its scheme reads, so `--report-only` with the
TRUAV flags does not find the SAC's cells).

    python docs/scripts/combine_cells.py OUT_DIR CELLS_DIR [--window N]

Every cell file in CELLS_DIR (named by the runner: <scheme>_v<speed>_..._s<a>-<b>_e<episodes>_<hash>.npz)
is loaded and the outputs go to OUT_DIR, as `truav experiment velocity` writes them.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from truav.config import Config
from truav.experiments.runner import Cell, load_cell
from truav.experiments.velocity import write_outputs

NAME = re.compile(r"(?P<scheme>[a-z_]+)_v(?P<speed>[0-9.]+)_u\d+_n\d+_s(?P<a>\d+)-(?P<b>\d+)_e(?P<episodes>\d+)_")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out")
    p.add_argument("cells")
    p.add_argument("--window", type=int, default=100)
    args = p.parse_args()
    results = []
    for f in sorted(Path(args.cells).glob("*.npz")):
        m = NAME.match(f.name)
        if m is None:
            continue
        import numpy as np
        with np.load(f) as d:
            seeds = tuple(int(s) for s in d["seeds"])
            eval_episodes = d["eval/coverage_pct"].shape[0]
        cell = Cell(m["scheme"], float(m["speed"]), seeds, int(m["episodes"]), eval_episodes)
        results.append(load_cell(f, cell))
    Path(args.out).mkdir(parents=True, exist_ok=True)
    for path in write_outputs(Path(args.out), Config(), results, args.window):
        print(path)


if __name__ == "__main__":
    main()

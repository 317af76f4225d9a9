"""Coverage versus UAV speed under --preset paper at the paper's budget: TRUAV's designs beside the
baselines, under the scenario's oracle ceilings (issue 32).

    python docs/scripts/designs_vs_speed.py docs/figures/velocity_designs_paper.png \
        --table "TRUAV (best state design)=docs/figures/velocity_paper_full.md" \
        --table "TRUAV + difference reward=docs/figures/velocity_paper_difference.md" \
        --oracles docs/figures/oracle_ceiling_paper*.json

Each --table is LABEL=FILE, FILE a `truav experiment velocity` summary.md; its `truav` rows are drawn under
LABEL, and the first table's other schemes (patrol, central) under their own names. --oracles: the JSON files
of docs/scripts/oracle_ceiling.py (one per speed); their teleport and reachable means per speed are drawn
as the ceiling.
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

ROW = re.compile(r"^\| (?P<scheme>[a-z_]+) \| (?P<speed>[0-9.]+) \| (?P<mean>[0-9.]+) ± (?P<ci>[0-9.]+) \|")


def read_table(path: Path) -> dict[str, dict[float, tuple[float, float]]]:
    """{scheme: {speed: (coverage mean, 95% half-width)}} from a summary.md table."""
    out: dict[str, dict[float, tuple[float, float]]] = {}
    for line in path.read_text().splitlines():
        m = ROW.match(line)
        if m:
            out.setdefault(m["scheme"], {})[float(m["speed"])] = (float(m["mean"]), float(m["ci"]))
    if not out:
        raise SystemExit(f"{path}: no summary table rows")
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out")
    p.add_argument("--table", action="append", required=True, metavar="LABEL=FILE")
    p.add_argument("--oracles", nargs="*", default=[])
    a = p.parse_args()
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from truav.experiments.report import SCHEME_STYLE
    fig, ax = plt.subplots(figsize=(8, 6))
    oracles = sorted((json.loads(Path(f).read_text()) for f in a.oracles), key=lambda d: d["speed_mps"])
    if oracles:
        x = [d["speed_mps"] for d in oracles]
        ax.plot(x, [d["teleport"]["mean"] for d in oracles], "k:", lw=1.5, marker="+", ms=9,
                label="oracle ceiling: teleport")
        ax.plot(x, [d["reachable"]["mean"] for d in oracles], "k--", lw=1.5, marker="x",
                label="oracle ceiling: speed-limited chaser")
    designs = [item.split("=", 1) for item in a.table]
    markers = ("o", "D", "v", "P")
    for n, (label, file) in enumerate(designs):
        table = read_table(Path(file))
        series = [("truav", label, f"C{0 if n == 0 else n + 3}", markers[n % len(markers)])]
        if n == 0:
            series += [(s, SCHEME_STYLE[s][0], SCHEME_STYLE[s][1], SCHEME_STYLE[s][2]) for s in table if s != "truav"]
        for scheme, name, color, marker in series:
            pts = sorted(table.get(scheme, {}).items())
            if not pts:
                continue
            # each further design a little to the right, so that overlapping intervals stay apart
            x, y, ci = [s + 0.3 * n for s, _ in pts], [m for _, (m, _) in pts], [c for _, (_, c) in pts]
            ax.errorbar(x, y, yerr=ci, color=color, marker=marker, capsize=3, lw=1.8,
                        label=name + (" (15 m/s only)" if len(pts) == 1 else ""))
    ax.set_xlabel("UAV velocity (m/s)")
    ax.set_ylabel("greedy coverage (% of vehicles)")
    ax.set_ylim(0, 100)
    ax.set_xticks([5, 10, 15, 20, 25])
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=2)
    ax.set_title("Coverage vs speed, --preset paper, 10 seeds x 5000 episodes (mean ± 95%)", fontsize=10)
    fig.tight_layout()
    fig.savefig(a.out, dpi=110)
    print(a.out)


if __name__ == "__main__":
    main()

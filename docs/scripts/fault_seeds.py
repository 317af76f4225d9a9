"""The fault comparison over seeds: TRUAV, the heuristic, the learned policy and the patrol as swarms on the bus,
each fault paired with the same seed's no-fault run (docs/results/fault-comparison.md, "Over seeds").

    python docs/scripts/fault_seeds.py --qtable RUN --runs runs/fault-seeds --out docs/figures/fault-seeds

For each seed k of --seeds, `truav experiment faults --schemes truav spread ppo patrol`'s comparison
(truav.swarm.scheme_faults.run_comparison) at the size SIZE below, under --preset paper with sensing 1500 m and
TRUAV's best state design (one grid cell), on held-out traffic (swarm seed EVAL_SEED_OFFSET + k): real-time swarm
runs of one episode each at no fault, beacon loss, latency, a crash of UAV 0 and a partition of UAVs 0-1 from
the rest. Every scheme flies one policy at every seed (TRUAV: --qtable's seed-0 table; ppo: the shipped
weights; spread and the patrol: no training), so a seed is a traffic draw. A re-run resumes the finished runs.
Writes OUT.csv (scheme, seed, fault, coverage, PDR, missed actions, peer beacons heard) and OUT.png (each scheme's drop in coverage
from its no-fault run, paired per seed, with 95% intervals) and prints the page's tables.
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

import numpy as np
import paired

from truav.config import Config
from truav.presets import preset_overrides
from truav.seeding import EVAL_SEED_OFFSET
from truav.stats import mean_ci
from truav.swarm.fault_sweep import PointFailed
from truav.swarm.scheme_faults import CompareSize, file_name, run_comparison

SCHEMES = (("truav", "TRUAV (Q-learning)"), ("spread", "spread (heuristic)"), ("ppo", "ppo (learned)"),
           ("patrol", "patrol"))
FAULTS = (("none", 0.0, "no fault"), ("loss", 0.5, "link loss 50%"), ("latency", 500.0, "latency 500 ms"),
          ("crash", 0.8, "UAV 0 crashed, never back"), ("partition", 0.8, "UAVs 0-1 cut off"))
SIZE = CompareSize(loss=(0.0, 0.5), latency_ms=(0.0, 500.0), down_share=(0.0, 0.8), episodes=1, steps=60,
                   train_episodes={"truav": 1, "central": 1}, learn_episodes=1, partition_share=(0.0, 0.8))
SEEDS, RATE_HZ = 6, 10.0
RETRIES = 3


def config() -> Config:
    cfg = Config().replace(**preset_overrides("paper"))
    return cfg.replace(learner={"grid_cells": 1, "sense_range_m": 1500.0})


def measure(runs: Path, qtable: str, seeds: list[int], rate: float) -> list[dict]:
    rows = []
    for k in seeds:
        out = runs / f"seed{k}"
        for attempt in range(RETRIES + 1):  # a run that could not start (a busy host) is run again; finished ones kept
            try:
                run_comparison(config(), SIZE, out, tuple(s for s, _ in SCHEMES), seed=EVAL_SEED_OFFSET + k,
                               qtable=qtable, rate_hz=rate)
                break
            except PointFailed as e:
                if attempt == RETRIES:
                    raise
                print(f"seed {k}: {e}; again", flush=True)
        with open(out / "comparison.csv", newline="") as f:
            for r in csv.DictReader(f):
                level = float(r["level"])
                fault = "none" if level == 0.0 else r["kind"]
                if fault == "none" and r["kind"] != "loss":  # the baseline is repeated under every kind
                    continue
                run = out / f"{file_name(r['scheme'])}-{'none' if fault == 'none' else r['kind']}-{level:g}"
                rows.append({"scheme": r["scheme"], "seed": k, "fault": fault,
                             "coverage_pct": float(r["coverage_pct"]), "pdr_pct": 100.0 * float(r["pdr"]),
                             "missed_actions_pct": missed_pct(run / "summary.json"),
                             "beacons_heard_pct": heard_pct(run / "summary.json")})
    return rows


def missed_pct(summary: Path) -> float:
    """UAV-ticks with no action in time (the world hovered the UAV), % of all: the crashed UAV's and a busy host's.
    (comparison.csv's missed_actions also counts the hover answers, which spread and ppo choose as an action.)"""
    d = json.loads(summary.read_text())
    w = d.get("world") or {}
    acting = w.get("ticks", 0) - len(w.get("episodes") or [])
    n = len(d.get("agents") or [])
    return 100.0 * w.get("deadline_misses", 0) / (acting * n) if acting > 0 and n else float("nan")


def heard_pct(summary: Path) -> float:
    """Peer beacons the agents heard, % of one from every peer every tick (the patrol beacons only to deploy)."""
    d = json.loads(summary.read_text())
    agents = [a for a in d.get("agents") or [] if a]
    ticks, n = (d.get("world") or {}).get("ticks", 0), len(d.get("agents") or [])
    heard = sum(sum(a.get("beacons_heard") or []) for a in agents)
    return 100.0 * heard / (ticks * n * (n - 1)) if ticks and n > 1 else float("nan")


def table(rows: list[dict]) -> dict[tuple[str, str], np.ndarray]:
    seeds = sorted({r["seed"] for r in rows})
    return {(s, f): np.array([next(r["coverage_pct"] for r in rows if (r["scheme"], r["fault"], r["seed"]) == (s, f, k))
                              for k in seeds]) for s, _ in SCHEMES for f, _, _ in FAULTS}


def missed(rows: list[dict], scheme: str, fault: str) -> float:
    return float(np.mean([r["missed_actions_pct"] for r in rows if (r["scheme"], r["fault"]) == (scheme, fault)]))


def tables(rows: list[dict]) -> str:
    cov = table(rows)
    n = len(cov[SCHEMES[0][0], "none"])
    lines = paired.head("scheme", [label for _, _, label in FAULTS])
    for s, label in SCHEMES:
        lines.append(paired.row(label, [f"{paired.ci(cov[s, f])} ({missed(rows, s, f):.0f}%)" for f, _, _ in FAULTS]))
    lines += ["", *paired.head("scheme", [f"{label} - no fault" for _, _, label in FAULTS[1:]])]
    for s, label in SCHEMES:
        lines.append(paired.row(label, [paired.diff(cov[s, "none"], cov[s, f]) for f, _, _ in FAULTS[1:]]))
    pairs = (("ppo", "truav"), ("ppo", "spread"), ("spread", "truav"))
    lines += ["", *paired.head("change of ... minus change of ...", [label for _, _, label in FAULTS[1:]])]
    for a, b in pairs:  # (a's fault - a's none) - (b's fault - b's none), paired per seed
        lines.append(paired.row(f"{a} - {b}", [paired.diff(cov[b, f] - cov[b, "none"], cov[a, f] - cov[a, "none"])
                                               for f, _, _ in FAULTS[1:]]))
    lines += ["", *paired.head("peer beacons heard (% of one a peer a tick)", [label for _, _, label in FAULTS])]
    for s, label in SCHEMES:
        lines.append(paired.row(label, [
            "{:.0f}".format(np.mean([r["beacons_heard_pct"] for r in rows if (r["scheme"], r["fault"]) == (s, f)]))
            for f, _, _ in FAULTS]))
    lines.append(f"\n({n} seeds; in brackets: UAV-ticks without an action in time, %, mean over seeds)")
    return "\n".join(lines)


def figure(rows: list[dict], path: Path) -> None:
    cov = table(rows)
    n = len(cov[SCHEMES[0][0], "none"])
    fig, ax = paired.pyplot().subplots(figsize=(8, 4.2))
    width = 0.8 / len(SCHEMES)
    for i, (s, label) in enumerate(SCHEMES):
        m, h = zip(*(mean_ci(cov[s, f] - cov[s, "none"]) for f, _, _ in FAULTS[1:]))
        x = np.arange(len(FAULTS) - 1) + (i - (len(SCHEMES) - 1) / 2) * width
        ax.bar(x, m, width, yerr=np.nan_to_num(h), capsize=3, color=f"C{i}", label=label)
    ax.axhline(0, color="k", lw=0.8)
    ax.set_xticks(np.arange(len(FAULTS) - 1), [label for _, _, label in FAULTS[1:]], fontsize=8)
    ax.set_ylabel("coverage change from no fault (points)")
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    ax.set_title(f"Swarms on the bus, --preset paper 15 m/s, 60-step episodes: fault minus no fault, paired over {n} seeds, "
                 "95% intervals", fontsize=9)
    paired.save(fig, path)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--qtable", help="TRUAV's trained run (truav train ... --set scenario.steps_per_episode=60)")
    ap.add_argument("--runs", default="runs/fault-seeds", help="the swarm runs, one directory per seed")
    ap.add_argument("--out", default="docs/figures/fault-seeds", help="OUT.csv and OUT.png (default %(default)s)")
    ap.add_argument("--seeds", type=int, default=SEEDS)
    ap.add_argument("--rate", type=float, default=RATE_HZ, help="tick rate in Hz (default %(default)s)")
    ap.add_argument("--only", type=int, nargs="+", metavar="K",
                    help="run only these seeds and write nothing (two hosts or processes can share the seeds; "
                         "a final run without --only resumes them all and writes OUT)")
    ap.add_argument("--replot", action="store_true", help="redraw OUT.png and the tables from OUT.csv")
    args = ap.parse_args()
    out = Path(args.out)
    if args.replot:
        with open(out.with_suffix(".csv"), newline="") as f:
            rows = [{**r, "seed": int(r["seed"]), **{k: float(r[k]) for k in
                                                     ("coverage_pct", "pdr_pct", "missed_actions_pct", "beacons_heard_pct")}}
                    for r in csv.DictReader(f)]
    else:
        if not args.qtable:
            ap.error("--qtable RUN is required (or --replot)")
        if args.only:
            measure(Path(args.runs), args.qtable, args.only, args.rate)
            return
        rows = measure(Path(args.runs), args.qtable, list(range(args.seeds)), args.rate)
        with open(out.with_suffix(".csv"), "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows({**r, **{k: f"{r[k]:.4f}" for k in ("coverage_pct", "pdr_pct", "missed_actions_pct", "beacons_heard_pct")}}
                        for r in rows)
    figure(rows, out.with_suffix(".png"))
    print(tables(rows))


if __name__ == "__main__":
    main()

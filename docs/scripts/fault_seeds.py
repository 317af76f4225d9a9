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
from dataclasses import replace
from pathlib import Path

import numpy as np
import paired

from truav.config import Config
from truav.presets import preset_overrides
from truav.seeding import EVAL_SEED_OFFSET
from truav.stats import mean_ci
from truav.swarm.fault_sweep import PointFailed
from truav.swarm.scheme_faults import CompareSize, file_name, run_comparison

CLONE = "agents.ppo_agent:PpoClaimAgent"
SCHEMES = (("truav", "TRUAV (Q-learning)"), ("spread", "spread (heuristic)"), ("ppo", "ppo (learned)"),
           ("patrol", "patrol"), ("claim", "claim (heuristic)"), (CLONE, "ppo-claim (learned clone of claim)"),
           ("ppo-disc", "ppo-disc (learned, senses the disc)"))
SHORT = {CLONE: "ppo-claim"}
"""A scheme's name in the tables' differences."""
FAULTS = (("none", 0.0, "no fault"), ("loss", 0.5, "link loss 50%"), ("latency", 500.0, "latency 500 ms"),
          ("crash", 0.8, "UAV 0 crashed, never back"), ("partition", 0.8, "UAVs 0-1 cut off"))
SIZE = CompareSize(loss=(0.0, 0.5), latency_ms=(0.0, 500.0), down_share=(0.0, 0.8), episodes=1, steps=60,
                   train_episodes={"truav": 1, "central": 1}, learn_episodes=1, partition_share=(0.0, 0.8))
BEACON_FIRST = replace(SIZE, latency_ms=(0.0,), down_share=(0.0,))
"""The beacon faults (loss, partition) of SIZE alone: every seed's run first, before the rest of SIZE."""
SEEDS, RATE_HZ, SPEED_MPS = 6, 10.0, 15.0
"""SPEED_MPS: the page's UAV speed (--preset paper's); ppo-disc flies its own network only below
agents.ppo_agent.DISC_BELOW_MPS (--speed 5), ppo-claim's from it on."""
RETRIES = 3


def config(speed: float = SPEED_MPS) -> Config:
    """Every scheme's config (truav.swarm.scheme_faults adds learner.sense_disc for ppo-disc: with_sensing)."""
    cfg = Config().replace(**preset_overrides("paper"))
    return cfg.replace(learner={"grid_cells": 1, "sense_range_m": 1500.0}, scenario={"uav_speed_mps": speed})


def measure(runs: Path, qtable: str | None, seeds: list[int], rate: float, schemes: tuple[str, ...],
            faults: tuple[str, ...], speed: float = SPEED_MPS) -> list[dict]:
    sizes = [BEACON_FIRST, SIZE] if {"latency", "crash"} & set(faults) else [BEACON_FIRST]
    for size in sizes:  # the beacon faults at every seed first, then the rest (resuming the finished runs)
        for k in seeds:
            for attempt in range(RETRIES + 1):  # a run that could not start (a busy host) is run again
                try:
                    run_comparison(config(speed), size, runs / f"seed{k}", schemes, seed=EVAL_SEED_OFFSET + k,
                                   qtable=qtable, rate_hz=rate)
                    break
                except PointFailed as e:
                    if attempt == RETRIES:
                        raise
                    print(f"seed {k}: {e}; again", flush=True)
    rows = []
    for k in seeds:
        out = runs / f"seed{k}"
        with open(out / "comparison.csv", newline="") as f:
            for r in csv.DictReader(f):
                level = float(r["level"])
                fault = "none" if level == 0.0 else r["kind"]
                if fault == "none" and r["kind"] != "loss" or fault not in faults:  # the baseline is under every kind
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
    """Coverage per (scheme, fault), one value per seed (nan where that run is not in the rows)."""
    seeds = sorted({r["seed"] for r in rows})
    cov = {(r["scheme"], r["fault"], r["seed"]): r["coverage_pct"] for r in rows}
    return {(s, f): np.array([cov.get((s, f, k), np.nan) for k in seeds]) for s, _ in SCHEMES for f, _, _ in FAULTS}


def cell(values: np.ndarray, text) -> str:
    return "not run" if np.isnan(values).any() else text()


def missed(rows: list[dict], scheme: str, fault: str, key: str = "missed_actions_pct") -> float:
    return float(np.mean([r[key] for r in rows if (r["scheme"], r["fault"]) == (scheme, fault)] or [np.nan]))


def tables(rows: list[dict]) -> str:
    cov = table(rows)
    n = len(cov[SCHEMES[0][0], "none"])
    lines = paired.head("scheme", [label for _, _, label in FAULTS])
    for s, label in SCHEMES:
        lines.append(paired.row(label, [cell(cov[s, f], lambda: f"{paired.ci(cov[s, f])} ({missed(rows, s, f):.0f}%)")
                                        for f, _, _ in FAULTS]))
    lines += ["", *paired.head("scheme", [f"{label} - no fault" for _, _, label in FAULTS[1:]])]
    for s, label in SCHEMES:
        lines.append(paired.row(label, [cell(cov[s, f], lambda: paired.diff(cov[s, "none"], cov[s, f]))
                                        for f, _, _ in FAULTS[1:]]))
    pairs = (("ppo", "truav"), ("ppo", "spread"), ("spread", "truav"), (CLONE, "truav"), (CLONE, "spread"),
             (CLONE, "claim"), (CLONE, "ppo"), ("claim", "spread"), ("ppo-disc", "spread"), ("ppo-disc", "claim"))
    lines += ["", *paired.head("change of ... minus change of ...", [label for _, _, label in FAULTS[1:]])]
    for a, b in pairs:  # (a's fault - a's none) - (b's fault - b's none), paired per seed
        lines.append(paired.row(f"{SHORT.get(a, a)} - {SHORT.get(b, b)}", [
            cell(cov[a, f] + cov[b, f], lambda: paired.diff(cov[b, f] - cov[b, "none"], cov[a, f] - cov[a, "none"]))
            for f, _, _ in FAULTS[1:]]))
    lines += ["", *paired.head("peer beacons heard (% of one a peer a tick)", [label for _, _, label in FAULTS])]
    for s, label in SCHEMES:
        lines.append(paired.row(label, [cell(cov[s, f], lambda: f"{missed(rows, s, f, 'beacons_heard_pct'):.0f}")
                                        for f, _, _ in FAULTS]))
    lines.append(f"\n({n} seeds; in brackets: UAV-ticks without an action in time, %, mean over seeds)")
    return "\n".join(lines)


def title(n: int, speed: float) -> str:
    return (f"Swarms on the bus, --preset paper {speed:g} m/s, 60-step episodes: fault minus no fault, paired over {n} "
            "seeds, 95% intervals")


def figure(rows: list[dict], path: Path, speed: float = SPEED_MPS) -> list[str]:
    """OUT.png, a bar per scheme in the rows (each in its colour of SCHEMES); the schemes drawn."""
    cov = table(rows)
    n = len(cov[SCHEMES[0][0], "none"])
    fig, ax = paired.pyplot().subplots(figsize=(10, 5))
    present = {r["scheme"] for r in rows}
    drawn = [(i, s, label) for i, (s, label) in enumerate(SCHEMES) if s in present]
    width = 0.8 / len(drawn)
    for j, (i, s, label) in enumerate(drawn):
        m, h = zip(*(mean_ci(cov[s, f] - cov[s, "none"]) for f, _, _ in FAULTS[1:]))
        x = np.arange(len(FAULTS) - 1) + (j - (len(drawn) - 1) / 2) * width
        ax.bar(x, m, width, yerr=np.nan_to_num(h), capsize=2, error_kw={"elinewidth": 1, "ecolor": "0.25"}, color=f"C{i}", label=label,
               hatch="//" if "learned" in label else None, edgecolor="white" if "learned" in label else None)
    ax.axhline(0, color="k", lw=0.8)
    ax.set_xticks(np.arange(len(FAULTS) - 1), [label for _, _, label in FAULTS[1:]], fontsize=8)
    ax.set_ylabel("coverage change from no fault (points)")
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8, ncol=3, loc="upper center", bbox_to_anchor=(0.5, -0.08), frameon=False)
    ax.set_title(title(n, speed), fontsize=9)
    paired.save(fig, path)
    return [s for _, s, _ in drawn]


def read(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return [{**r, "seed": int(r["seed"]), **{k: float(r[k]) for k in
                                                 ("coverage_pct", "pdr_pct", "missed_actions_pct", "beacons_heard_pct")}}
                for r in csv.DictReader(f)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--qtable", help="TRUAV's trained run (truav train ... --set scenario.steps_per_episode=60)")
    ap.add_argument("--runs", default="runs/fault-seeds", help="the swarm runs, one directory per seed")
    ap.add_argument("--out", default="docs/figures/fault-seeds", help="OUT.csv and OUT.png (default %(default)s)")
    ap.add_argument("--seeds", type=int, default=SEEDS)
    ap.add_argument("--speed", type=float, default=SPEED_MPS,
                    help="UAV speed in m/s, scenario.uav_speed_mps (default %(default)g, the page's)")
    ap.add_argument("--rate", type=float, default=RATE_HZ, help="tick rate in Hz (default %(default)s)")
    ap.add_argument("--only", type=int, nargs="+", metavar="K",
                    help="run only these seeds and write nothing (two hosts or processes can share the seeds; "
                         "a final run without --only resumes them all and writes OUT)")
    ap.add_argument("--schemes", nargs="+", default=[s for s, _ in SCHEMES], choices=[s for s, _ in SCHEMES],
                    help="run only these schemes; OUT.csv keeps the other schemes' rows (default: all)")
    ap.add_argument("--faults", nargs="+", default=[f for f, _, _ in FAULTS], choices=[f for f, _, _ in FAULTS],
                    help="write only these faults' rows (the beacon faults loss and partition run first; default: all)")
    ap.add_argument("--replot", action="store_true", help="redraw OUT.png and the tables from OUT.csv")
    args = ap.parse_args()
    out = Path(args.out)
    schemes, faults = tuple(args.schemes), tuple(dict.fromkeys(["none", *args.faults]))
    if args.replot:
        rows = read(out.with_suffix(".csv"))
    else:
        if not args.qtable and "truav" in schemes:
            ap.error("--qtable RUN is required to fly truav (or --replot)")
        seeds = args.only or list(range(args.seeds))
        new = measure(Path(args.runs), args.qtable, seeds, args.rate, schemes, faults, args.speed)
        if args.only:
            return
        old = read(out.with_suffix(".csv")) if out.with_suffix(".csv").is_file() else []
        rows = [r for r in old if r["scheme"] not in schemes] + new
        with open(out.with_suffix(".csv"), "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows({**r, **{k: f"{r[k]:.4f}" for k in ("coverage_pct", "pdr_pct", "missed_actions_pct", "beacons_heard_pct")}}
                        for r in rows)
    figure(rows, out.with_suffix(".png"), args.speed)
    print(tables(rows))


if __name__ == "__main__":
    main()

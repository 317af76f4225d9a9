"""`truav-swarm chaos --plan FILE`: the same seed with and without a fault
plan, side by side: a degradation table (coverage, PDR, delay, energy,
missed actions, tick lateness) and a figure with the fault windows shaded."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from truav.config import Config  # noqa: E402
from truav.faults import load_plan  # noqa: E402
from truav.swarm.supervisor import SwarmOptions, run_swarm  # noqa: E402

ROWS = (("coverage_pct", "coverage %", 1.0), ("pdr", "PDR %", 100.0), ("delay_ms", "relay delay ms", 1.0),
        ("energy_j", "energy kJ/UAV/episode", 1e-3))


def _load(out: Path) -> dict:
    return json.loads((out / "summary.json").read_text())


def _mean_episode(summary: dict, key: str) -> float:
    eps = (summary.get("world") or {}).get("episodes") or []
    vals = [e.get(key, math.nan) for e in eps]
    return float(np.nanmean(vals)) if vals else math.nan


def degradation_table(base: dict, faulted: dict) -> str:
    lines = [f"{'metric':<24}{'no faults':>12}{'with plan':>12}{'change':>10}", "-" * 58]
    for key, label, scale in ROWS:
        a, b = _mean_episode(base, key) * scale, _mean_episode(faulted, key) * scale
        change = f"{100 * (b - a) / abs(a):+.1f}%" if a and math.isfinite(a) and math.isfinite(b) else "n/a"
        lines.append(f"{label:<24}{a:12.2f}{b:12.2f}{change:>10}")
    for key, label in (("deadline_misses", "missed actions"), ("ticks", "ticks")):
        a, b = (base.get("world") or {}).get(key, math.nan), (faulted.get("world") or {}).get(key, math.nan)
        lines.append(f"{label:<24}{a:12}{b:12}")
    la = ((base.get("world") or {}).get("tick_lateness_ms") or {}).get("p99", math.nan)
    lb = ((faulted.get("world") or {}).get("tick_lateness_ms") or {}).get("p99", math.nan)
    lines.append(f"{'tick lateness p99 ms':<24}{la:12.2f}{lb:12.2f}")
    return "\n".join(lines)


def chaos_figure(base: dict, faulted: dict, plan_path: str, rate_hz: float, path: Path) -> Path:
    plan = load_plan(plan_path)
    fig, axes = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
    for summary, label, color in ((base, "no faults", "C0"), (faulted, "with plan", "C3")):
        cov = np.array(summary["timeline"]["coverage"] or [[0, np.nan]])
        hov = np.array(summary["timeline"]["hovering"] or [[0, np.nan]])
        axes[0].plot(cov[:, 0] / rate_hz, cov[:, 1], color=color, lw=1, label=label)
        axes[1].plot(hov[:, 0] / rate_hz, hov[:, 1], color=color, lw=1, label=label)
    end = max(len(faulted["timeline"]["coverage"]), 1) / rate_hz
    for n, f in enumerate(plan.faults):
        stop = min(f.end, end) if f.kind != "crash" else f.start + f.params.get("restart_after", end - f.start)
        for ax in axes:
            ax.axvspan(f.start, stop, color=f"C{2 + n % 6}", alpha=0.15, lw=0)
        axes[0].text(f.start, axes[0].get_ylim()[1], f" {f.kind}", va="top", fontsize=8)
    axes[0].set_ylabel("coverage (%)")
    axes[1].set_ylabel("UAVs without action")
    axes[1].set_xlabel("time since tick 0 (s)")
    axes[0].legend(loc="lower right")
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.suptitle(f"chaos: {Path(plan_path).name} (fault windows shaded)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def run_chaos(cfg: Config, opts: SwarmOptions, plan_path: str) -> int:
    load_plan(plan_path)  # fail early on a bad plan
    out = Path(opts.out or f"runs/chaos-{opts.run}")
    results = {}
    for name, plan in (("baseline", None), ("faulted", plan_path)):
        print(f"== {name} run ==", flush=True)
        run_opts = dataclasses.replace(opts, out=str(out / name), fault_plan=plan, plot=False,
                                       record=str(out / f"{name}.mcap") if opts.record else None)
        rc = run_swarm(cfg, run_opts)
        if rc:
            return rc
        results[name] = _load(out / name)
    table = degradation_table(results["baseline"], results["faulted"])
    print(f"\n== degradation under {plan_path} (seed {opts.seed}) ==\n{table}")
    (out / "degradation.txt").write_text(table + "\n")
    path = chaos_figure(results["baseline"], results["faulted"], plan_path, opts.rate_hz, out / "chaos.png")
    print(f"figure: {path}")
    return 0

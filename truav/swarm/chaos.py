"""`truav-swarm chaos --plan FILE`: the same seed with and without a fault
plan, side by side: a degradation table (coverage, PDR, delay, energy,
missed actions, tick lateness) and a figure with the fault windows shaded.

`truav-swarm chaos --nemesis random --duration 10m --seed S`: a soak.  A
seeded random plan (truav.nemesis), written to <out>/nemesis-plan.toml (so
`chaos --plan` of it runs the same schedule again), flies one recorded run;
no baseline.  After either, the checker (truav.swarm.invariants) reports its
invariants on the faulted run as a table, in <out>/invariants.txt and .json,
and `chaos` exits 1 on a violation."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from truav import jsonio  # noqa: E402
from truav.analysis.swarm_plots import fault_lanes  # noqa: E402
from truav.config import Config  # noqa: E402
from truav.faults import FaultPlan, load_plan  # noqa: E402
from truav.nemesis import heal_at, random_plan  # noqa: E402
from truav.stats import Effect, effect_text, paired_effect  # noqa: E402
from truav.swarm import chaos_resume, invariants  # noqa: E402
from truav.swarm.chaos_time import announce  # noqa: E402
from truav.swarm.outdir import CHAOS_RUNS, OutDirError, hold_run_dirs, prepare_chaos_dir  # noqa: E402
from truav.swarm.supervisor import SwarmOptions, run_swarm  # noqa: E402

ROWS = (("coverage_pct", "coverage %", 1.0), ("pdr", "PDR %", 100.0), ("delay_ms", "relay delay ms", 1.0),
        ("energy_j", "energy kJ/UAV/episode", 1e-3))


def _load(out: Path) -> dict:
    return json.loads((out / "summary.json").read_text())


def _mean_episode(summary: dict, key: str) -> float:
    vals = _per_episode(summary, key)
    return float(np.nanmean(vals)) if vals else math.nan


def _per_episode(summary: dict, key: str) -> list[float]:
    return [jsonio.num(e.get(key)) for e in (summary.get("world") or {}).get("episodes") or []]


def effects(base: dict, faulted: dict) -> dict[str, Effect]:
    """Each metric's effect of the plan, paired over the episodes both runs finished (the same seed: episode k
    of either run drives the same traffic, so the pair differs by the plan and the host's timing only)."""
    out = {}
    for key, label, scale in ROWS:
        a, b = _per_episode(base, key), _per_episode(faulted, key)
        n = min(len(a), len(b))
        out[label] = paired_effect(np.array(a[:n]) * scale, np.array(b[:n]) * scale)
    return out


def effects_table(base: dict, faulted: dict) -> str:
    """The effects of :func:`effects`, one line each, with their 95% interval or why there is none."""
    found = effects(base, faulted)
    n = max((e.n for e in found.values()), default=0)
    lines = [f"effect of the plan (with - without), paired over {n} episode(s), 95% t-interval:"]
    lines += [f"  {label:<24}{effect_text(e, noun='episodes')}" for label, e in found.items()]
    return "\n".join(lines)


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


def chaos_figure(base: dict, faulted: dict, plan_path: str, rate_hz: float, path: Path,
                 plan: FaultPlan | None = None) -> Path:
    """Coverage and missed actions with and without the plan; the plan's faults on their own lanes
    above (a bar per window, a cross for a crash), so overlapping windows never blend."""
    plan = plan if plan is not None else load_plan(plan_path)
    n = len(plan.faults)
    fig, axes = plt.subplots(3, 1, figsize=(11, 6.5 + 0.22 * n), sharex=True,
                             gridspec_kw={"height_ratios": [0.5 + 0.28 * max(n, 1), 3, 1.6]})
    lanes_ax, cov_ax, hov_ax = axes
    # The baseline wide and pale under the faulted run: where the two coincide both still show.
    for summary, label, color, lw, alpha in ((base, "no faults", "C0", 3.0, 0.5),
                                             (faulted, "with plan", "C3", 1.0, 1.0)):
        cov = np.array(summary["timeline"]["coverage"] or [[0, np.nan]])
        hov = np.array(summary["timeline"]["hovering"] or [[0, np.nan]])
        cov_ax.plot(cov[:, 0] / rate_hz, cov[:, 1], color=color, lw=lw, alpha=alpha, label=label)
        hov_ax.step(hov[:, 0] / rate_hz, hov[:, 1], where="mid", color=color, lw=lw, alpha=alpha, label=label)
    end = max(len(faulted["timeline"]["coverage"]), 1) / rate_hz
    for row, (label, start, stop, forever) in enumerate(fault_lanes(plan, end)):
        color = f"C{(2 + row) % 10}" if (2 + row) % 10 != 3 else "C9"
        y = n - 1 - row
        if stop is None:
            lanes_ax.plot([start], [y], marker="x", ms=9, mew=2, color=color, ls="none")
        else:
            lanes_ax.barh(y, stop - start, left=start, height=0.6, color=color, alpha=0.8)
        text = label + (" (no end)" if forever else "") + (" (no restart)" if stop is None else "")
        lanes_ax.text(max(start, 0.005 * end), y + 0.38, text, fontsize=7.5, va="bottom", color="0.2")
        for ax in (cov_ax, hov_ax):
            ax.axvline(start, color=color, lw=0.9, alpha=0.8)
            if stop is not None and not forever:
                ax.axvline(stop, color=color, lw=0.9, alpha=0.8, ls="--")
    lanes_ax.set_ylim(-0.6, n + 0.2)
    lanes_ax.set_yticks([])
    lanes_ax.set_title("faults of the plan (bar: active window; x: crash; lines below: start solid, end dashed)",
                       fontsize=9, loc="left")
    lanes_ax.grid(axis="x", alpha=0.3)
    cov_ax.set_ylabel("coverage (%)")
    hov_ax.set_ylabel("UAVs without\nan action")
    hov_ax.set_xlabel("time since tick 0 (s)")
    hov_ax.yaxis.get_major_locator().set_params(integer=True)
    # Above the plot, beside the lanes' title: inside the axes it covered the curves' ends.
    cov_ax.legend(loc="lower right", bbox_to_anchor=(1.0, 1.0), ncol=2, fontsize=8, frameon=False,
                  borderaxespad=0.2)
    for ax in (cov_ax, hov_ax):
        ax.grid(alpha=0.3)
    hov_ax.set_xlim(0, end)
    fig.suptitle(f"chaos: {Path(plan_path).name}, the same seed with and without the plan")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


BASELINE_MAX_MISSED_SHARE = invariants.HOST_LOAD_MISSED_SHARE
"""The no-fault baseline should miss (almost) no action: more than this and the host was too busy."""
BASELINE_MAX_LATENESS_FRAC = 0.5
"""...nor start its ticks late by more than this fraction of the tick period (p99)."""


def baseline_warning(base: dict, n_uavs: int, rate_hz: float) -> str | None:
    """Why the no-fault run cannot serve as a baseline (a loaded host, most often), or None."""
    world = base.get("world") or {}
    problems = []
    acting = world.get("ticks", 0) - len(world.get("episodes") or [])
    if acting > 0:
        missed = 1.0 - world.get("actions_received", 0) / (acting * n_uavs)
        if missed > BASELINE_MAX_MISSED_SHARE:
            problems.append(f"{100 * missed:.1f}% of its actions were missing")
    p99 = (world.get("tick_lateness_ms") or {}).get("p99")
    if p99 is not None and p99 > BASELINE_MAX_LATENESS_FRAC * 1e3 / rate_hz:
        problems.append(f"its ticks started up to {p99:.0f} ms late (p99; the period is {1e3 / rate_hz:.0f} ms)")
    if not problems:
        return None
    return ("the no-fault baseline is itself degraded (" + "; ".join(problems) + "): the host is probably "
            "loaded, and the changes below mix its load with the plan's faults; rerun on a quieter machine")


def run_chaos(cfg: Config, opts: SwarmOptions, plan_path: str, plan: FaultPlan | None = None) -> int:
    """The same seed without and with the plan at ``plan_path`` (``plan``: that file already parsed)."""
    parsed = plan if plan is not None else load_plan(plan_path)  # fails early on a bad plan
    out = Path(opts.out or f"runs/chaos-{opts.run}")
    now = chaos_resume.settings(cfg, opts, plan_path)
    with contextlib.ExitStack() as held:
        if not _hold(held, out, opts, resume=opts.resume):
            return 2
        try:  # before anything in out changes: which finished runs --resume keeps
            kept = chaos_resume.kept_runs(out, now, opts.episodes) if opts.resume else {}
        except OutDirError as exc:
            print(f"truav-swarm: error: {exc}", file=sys.stderr)
            return 2
        chaos_resume.start_fresh_comparison(out, now)
        progress = chaos_resume.Progress()
        try:
            return _run_chaos_held(cfg, opts, plan_path, parsed, out, kept, progress)
        except KeyboardInterrupt as exc:  # Ctrl-C, SIGTERM or SIGHUP, in a swarm run or between them
            print(progress.stopped_line(opts.resume), file=sys.stderr, flush=True)
            return chaos_resume.stop_code_of(exc)


def _hold(held: contextlib.ExitStack, out: Path, opts: SwarmOptions, *, resume: bool,
          runs: tuple[str, ...] = CHAOS_RUNS) -> bool:
    """Refuse or clear ``out`` and hold its run locks and its subruns' (so no other command writes there
    while the chaos run lasts); False once the refusal is told."""
    try:
        prepare_chaos_dir(out, resume=resume, force=opts.force, check_only=True)
        held.enter_context(hold_run_dirs([out, *(out / name for name in runs)], run=opts.run,
                                         command="truav-swarm chaos"))
        prepare_chaos_dir(out, resume=resume, force=opts.force)
    except OutDirError as exc:
        print(f"truav-swarm: error: {exc}", file=sys.stderr)
        return False
    return True


def _run_chaos_held(cfg: Config, opts: SwarmOptions, plan_path: str, parsed: FaultPlan, out: Path,
                    kept: dict[str, str], progress: chaos_resume.Progress) -> int:
    print(announce(opts.episodes, cfg.scenario.steps_per_episode, opts.rate_hz, opts.lockstep), flush=True)
    results = {}
    rc_faulted = 0
    for name, path in (("baseline", None), ("faulted", plan_path)):
        sub = out / name
        run_opts = dataclasses.replace(opts, out=str(sub), fault_plan=path, plan=parsed if path else None, plot=False,
                                       references=False,  # chaos compares the run with its own clean one
                                       record=str(out / f"{name}.mcap") if opts.record else None,
                                       # an unfinished run is made again from scratch, never continued
                                       resume=False, force=opts.force or opts.resume)
        progress.stage = f"the {name} run"
        if name in kept:
            print(f"== {name} run: finished before, kept ({sub}) ==", flush=True)
            rc = 0
        else:
            print(f"== {name} run ==", flush=True)
            rc = run_swarm(cfg, run_opts)
            chaos_resume.raise_if_stopped(rc, sub)
        if rc == 0 and chaos_resume.finished(sub, opts.episodes):
            progress.finished.append(name)
        if name == "faulted":  # the checker judges it, however it ended
            rc_faulted = rc
            progress.stage = "the check of the faulted run"
            record = run_opts.record if run_opts.record and Path(run_opts.record).exists() else None
            held = _check(out, sub, rc, parsed, opts, record)
            if rc or not held:
                return rc or 1
        elif rc:
            return rc
        results[name] = _load(sub)
    progress.stage = "the comparison of the two runs"
    table = degradation_table(results["baseline"], results["faulted"]) + "\n\n" + \
        effects_table(results["baseline"], results["faulted"])
    warning = baseline_warning(results["baseline"], cfg.scenario.n_uavs, opts.rate_hz)
    print(f"\n== degradation under {plan_path} (seed {opts.seed}) ==\n{table}")
    if warning:
        print(f"warning: {warning}", flush=True)
    (out / "degradation.txt").write_text(table + "\n" + (f"\nwarning: {warning}\n" if warning else ""))
    path = chaos_figure(results["baseline"], results["faulted"], plan_path, opts.rate_hz, out / "chaos.png", parsed)
    print(f"figure: {path}")
    return rc_faulted


def _check(out: Path, sub: Path, rc: int, plan: FaultPlan, opts: SwarmOptions, record: str | None) -> bool:
    """The checker's table on the faulted run, printed and written; whether none was violated (what was not
    checked is said in the table, not counted as held)."""
    if not (sub / "summary.json").is_file():  # it never started (a user mistake, told already)
        return False
    rows = invariants.check_run(sub, rc, plan, opts.rate_hz, record)
    txt, _ = invariants.write(out, rows)
    print(f"\n== invariants of the faulted run ({txt}) ==\n{invariants.table(rows)}", flush=True)
    return invariants.sound(rows)


NEMESIS_ROUTER_TIMEOUT_S = 30.0
"""World and agents wait this long for a killed router to come back in a nemesis run (see run_nemesis)."""


def run_nemesis(cfg: Config, opts: SwarmOptions, nemesis: str, duration_s: float) -> int:
    """A soak: one run under the nemesis's seeded random plan, then the checker (exit 1 on a violation)."""
    out = Path(opts.out or f"runs/chaos-{opts.run}")
    with contextlib.ExitStack() as held:
        if not _hold(held, out, opts, resume=False, runs=("faulted",)):
            return 2
        try:
            return _run_nemesis_held(cfg, opts, nemesis, duration_s, out)
        except KeyboardInterrupt as exc:  # a nemesis run starts afresh: no --resume
            print(f"truav-swarm: interrupted in the nemesis run; it cannot be resumed: run the same command with "
                  f"--force to start it afresh", file=sys.stderr, flush=True)
            return chaos_resume.stop_code_of(exc)


def _run_nemesis_held(cfg: Config, opts: SwarmOptions, nemesis: str, duration_s: float, out: Path) -> int:
    record = opts.record or str(out / "faulted.mcap")  # the recording is one of the invariants
    plan = random_plan(duration_s, cfg.scenario.n_uavs, opts.seed, central=opts.scheme == "central",
                       recording=True)
    plan_path = out / "nemesis-plan.toml"
    plan_path.write_text(plan.to_toml(
        f"truav-swarm chaos --nemesis {nemesis} --duration {duration_s:g}s --seed {opts.seed} "
        f"({cfg.scenario.n_uavs} agents, scheme {opts.scheme})\n"
        f"{len(plan.faults)} fault(s), all healed by {heal_at(duration_s):g} s after tick 0; run it again with\n"
        f"truav-swarm chaos --plan {plan_path} (same seed and flags: the same schedule)"))
    kinds: dict[str, int] = {}
    for f in plan.faults:
        label = f"{f.kind} {f.params['target']}" if "target" in f.params else f.kind
        kinds[label] = kinds.get(label, 0) + 1
    print(f"nemesis {nemesis} (seed {opts.seed}): {len(plan.faults)} fault(s) over {duration_s:g} s ("
          + ", ".join(f"{n} {k}" for k, n in sorted(kinds.items())) + f"), healed by {heal_at(duration_s):g} s; "
          f"plan {plan_path}", flush=True)
    sub = out / "faulted"
    timeout = opts.router_timeout_s
    if timeout < NEMESIS_ROUTER_TIMEOUT_S and any(f.params.get("target") == "router" for f in plan.faults):
        timeout = NEMESIS_ROUTER_TIMEOUT_S
        print(f"nemesis: --router-timeout {opts.router_timeout_s:g} raised to {timeout:g} s for its router kills "
              f"(a loaded host took 7 s to start a router, and clients reconnect with a backoff)", flush=True)
    run_opts = dataclasses.replace(opts, out=str(sub), fault_plan=str(plan_path), plan=plan, plot=False, record=record,
                                   references=False,
                                   resume=False, router_timeout_s=timeout)
    rc = run_swarm(cfg, run_opts)
    chaos_resume.raise_if_stopped(rc, sub)
    held = _check(out, sub, rc, plan, opts, record)
    return rc or (0 if held else 1)

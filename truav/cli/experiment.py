"""`truav experiment velocity | scale`: the paper's velocity sweep and the
scalability experiment, resumable, on every core.

    truav experiment velocity                     # full: 3 schemes x 5 speeds x 10 seeds x 5000 episodes
    truav experiment velocity --quick             # seconds: the CI-sized smoke run
    truav experiment velocity --episodes-for central=1000   # a smaller SAC budget
    truav experiment scale --episodes 1000        # 5/10/20 UAVs x 200/1000 vehicles, TRUAV vs centralized
    truav experiment velocity --executor ray [--address HEAD:6379]   # cells as Ray tasks

Re-running the same command resumes: finished cells (scheme, setting, seed
chunk) are skipped. --report-only rewrites the tables and figures from the
finished cells.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import time
from pathlib import Path
from typing import Any

from truav.analysis import runio
from truav.cli.args import check_out_dir, make_dir, positive_float, positive_int, seed_int
from truav.cli.config import UsageError, add_config_args, config_from
from truav.config import LearnerConfig, MOBILITIES
from truav.stopping import INTERRUPTS, is_interrupt
from truav.experiments import runner, scale, velocity
from truav.cli.experiment_executor import (  # noqa: F401  (re-exported)
    RAY_ADDRESS_RE, RAY_PROBE_TIMEOUT_S, add_executor_args, check_executor, check_ray_address)
from truav.cli.experiment_faults import add_fault_sweep_parser

QUICK_CONFIG: dict[str, dict[str, Any]] = {
    "scenario": {"n_vehicles": 60, "steps_per_episode": 20},
    "roads": {"warmup_steps": 20},
    "central": {"learning_starts": 40, "buffer_size": 2000, "batch_size": 16, "hidden": 16, "update_every": 2},
}
"""--quick: a small city and short episodes, every code path exercised in seconds."""
QUICK = {"seeds": 2, "episodes": 6, "eval_episodes": 2, "window": 3, "speeds": [5.0, 15.0, 25.0],
         "uavs": [2, 4], "vehicles": [30, 60]}
FULL = {"seeds": 10, "eval_episodes": 100, "window": 500, "scale_episodes": 1000}
"""The full run's sizes where a flag is not given (the help texts name these)."""


INTERRUPTED = 130
"""What a command stopped by a signal returns: run_main makes it 128 + the signal (143 for SIGTERM)."""


def _listed(values) -> str:
    return " ".join(f"{v:g}" for v in values)


def _parse_episodes_for(items: list[str], schemes, default: int) -> dict[str, int]:
    out = {s: default for s in schemes}
    for item in items:
        name, _, value = item.partition("=")
        if name not in schemes or not value.isdigit() or int(value) < 1:
            raise UsageError(f"--episodes-for expects SCHEME=N with SCHEME in {', '.join(schemes)}, got {item!r}")
        out[name] = int(value)
    return out


def _check_schemes(schemes, cfg) -> None:
    """Each --schemes name a built-in scheme or an agent class, found and checked (one line, exit 2)."""
    from truav.analysis import agent_loader
    for name in schemes:
        if name not in velocity.CHOICES:
            agent_loader.load(name, cfg, flag="--schemes")
    if "central" in schemes and importlib.util.find_spec("torch") is None:
        raise UsageError("the centralized baseline needs PyTorch: pip install -e '.[central]' "
                         "(or leave it out: --schemes truav patrol)")


def _common(p: argparse.ArgumentParser, schemes, default_schemes, episodes_help: str) -> None:
    add_config_args(p)
    p.add_argument("--mobility", choices=MOBILITIES,
                   help="vehicle mobility: builtin (the grid's IDM) or sumo (SUMO traces, built and cached before "
                        "the cells run; `truav traffic build`) (default: scenario.mobility, builtin)")
    p.add_argument("--schemes", nargs="+", default=list(default_schemes), metavar="SCHEME",
                   help=f"schemes to run: {', '.join(schemes)}, or an agent class (pkg.module:Class or a name "
                        f"registered in the entry-point group truav.agents, e.g. random; docs/how-to/your-own-agent.md) "
                        f"(default: {' '.join(default_schemes)})")
    p.add_argument("--seeds", type=positive_int, help=f"number of seeds (default {FULL['seeds']})")
    p.add_argument("--seed-start", type=seed_int, default=0, help="first seed (default %(default)s)")
    p.add_argument("--episodes", type=positive_int, help=episodes_help)
    p.add_argument("--episodes-for", action="append", default=[], metavar="SCHEME=N",
                   help="training episodes of one scheme (repeatable), e.g. central=1000")
    p.add_argument("--eval-episodes", type=positive_int,
                   help=f"greedy evaluation episodes per seed (default {FULL['eval_episodes']})")
    p.add_argument("--window", type=positive_int,
                   help=f"episodes per training window in the tidy CSV (default {FULL['window']})")
    p.add_argument("--seeds-per-cell", type=positive_int, default=5,
                   help="seeds run as one batch per cell (default %(default)s); changing it re-runs cells")
    p.add_argument("--workers", type=positive_int, default=os.cpu_count() or 1,
                   help="worker processes (default: all cores)")
    p.add_argument("--out", help="output directory (resumed if it holds finished cells)")
    p.add_argument("--quick", action="store_true",
                   help="CI-sized run: small city, a few short episodes (flags and --config/--set given "
                        "explicitly still win)")
    p.add_argument("--report-only", action="store_true", help="only rewrite tables and figures from finished cells")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_executor_args(p)


def add_experiment_parser(sub) -> None:
    """Register `truav experiment ...` on the main parser's subcommands."""
    ex = sub.add_parser("experiment", help="the paper's experiments (velocity sweep, scalability)",
                        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ex_sub = ex.add_subparsers(dest="experiment", required=True, metavar="EXPERIMENT")
    v = ex_sub.add_parser("velocity", help="schemes x speeds x seeds: CSV, summary, four-panel figure")
    _common(v, velocity.CHOICES, velocity.SCHEMES,
            f"training episodes per scheme (default learner.episodes, {LearnerConfig().episodes})")
    v.add_argument("--speeds", nargs="+", type=positive_float,
                   help=f"UAV speeds in m/s (default {_listed(velocity.SPEEDS)})")
    v.set_defaults(func=cmd_velocity)
    s = ex_sub.add_parser("scale", help="TRUAV vs centralized as UAVs and vehicles grow, with control traffic")
    _common(s, velocity.CHOICES, scale.SCHEMES, f"training episodes per scheme (default {FULL['scale_episodes']})")
    s.add_argument("--uavs", nargs="+", type=positive_int, help=f"swarm sizes (default {_listed(scale.UAVS)})")
    s.add_argument("--vehicles", nargs="+", type=positive_int,
                   help=f"vehicle counts (default {_listed(scale.VEHICLES)})")
    s.add_argument("--speed", type=positive_float, default=15.0, help="UAV speed in m/s (default %(default)g)")
    s.set_defaults(func=cmd_scale)
    add_fault_sweep_parser(ex_sub)  # truav experiment faults: beacon loss / latency sweep on the real swarm


def _setup(args, default_out: str, default_episodes: int | None):
    quick = args.quick
    # --quick only fills in what the user left out: an explicit flag, --config or --set wins.
    cfg = config_from(args, {"scenario": {"mobility": args.mobility}} if args.mobility else None,
                      base=QUICK_CONFIG if quick else None)
    if cfg.scenario.mobility == "sumo":  # one line naming what to install, before anything starts
        from truav.analysis import sumo_traffic
        sumo_traffic.sumo_home()

    def pick(given, quick_value, full_value):
        return given if given is not None else (quick_value if quick else full_value)

    n_seeds = pick(args.seeds, QUICK["seeds"], FULL["seeds"])
    seeds = list(range(args.seed_start, args.seed_start + n_seeds))
    base_ep = pick(args.episodes, QUICK["episodes"], default_episodes or cfg.learner.episodes)
    if not args.report_only:
        _check_schemes(args.schemes, cfg)
        check_executor(args)
    episodes = _parse_episodes_for(args.episodes_for, tuple(dict.fromkeys((*velocity.CHOICES, *args.schemes))),
                                   base_ep)
    eval_episodes = pick(args.eval_episodes, QUICK["eval_episodes"], FULL["eval_episodes"])
    window = pick(args.window, QUICK["window"], FULL["window"])
    out = check_out_dir("--out", args.out if args.out is not None else default_out + ("-quick" if quick else ""))
    return cfg, seeds, episodes, eval_episodes, window, out


def _run(args, cfg, out: Path, cells: list[runner.Cell], label: str) -> float | None:
    """Run the unfinished cells; the seconds it took, or None if a stop signal ended it (said in one line)."""
    make_dir("--out", out)
    runio.write_config(out, cfg)
    todo = runner.pending_cells(cfg, out, cells)
    if args.report_only:
        return 0.0
    total = sum(c.env_episodes for c in todo)
    where = (f"Ray at {args.address}" if args.address else f"a local Ray instance of {args.workers} CPU(s)") \
        if args.executor == "ray" else f"{max(1, min(args.workers, len(todo) or 1))} worker(s)"
    print(f"{label}: {len(cells)} cells, {len(cells) - len(todo)} already finished, {len(todo)} to run "
          f"on {where} -> {out}", flush=True)
    if not todo:
        return 0.0
    if cfg.scenario.mobility == "sumo":  # each cell's trace built once here; the workers only load them
        from truav.analysis import sumo_traffic
        for cell in todo:  # cached after the first of a scenario
            sumo_traffic.checked_trace(cell.config(cfg), say=lambda line: print(line, flush=True))
    from truav.analysis.warmup import ensure_compiled
    ensure_compiled(lambda line: print(line, flush=True))  # before the bar: its ETA counts episodes, not the compiler
    from tqdm import tqdm
    t0 = time.perf_counter()
    finished = [0]
    with tqdm(total=total, desc=label, unit="ep", disable=args.quiet, dynamic_ncols=True,
              bar_format="{l_bar}{bar}| {n_fmt}/{total_fmt} env-episodes [{elapsed}<{remaining}{postfix}]") as bar:
        def on_cell(cell, wall):
            finished[0] += 1
            bar.set_postfix_str(f"cells {finished[0]}/{len(todo)}; last {cell.scheme} {cell.speed:g} m/s "
                                f"{wall:.0f}s", refresh=True)
            if args.quiet:
                print(f"  cell {finished[0]}/{len(todo)}: {cell.scheme} {cell.speed:g} m/s seeds "
                      f"{cell.seeds[0]}-{cell.seeds[-1]} in {wall:.1f} s", flush=True)
        try:
            runner.run_cells(cfg, out, cells, args.workers, on_episode=bar.update, on_cell=on_cell,
                             executor=args.executor, address=args.address)
        except RuntimeError as exc:
            raise UsageError(f"{exc} (finished cells are kept; re-run the same command to resume)") from None
        except INTERRUPTS as exc:  # Ctrl-C, SIGTERM, SIGHUP: one line; run_main exits 128 + the signal
            if not is_interrupt(exc):
                raise
            bar.close()  # its last refresh before the line below, not after it
            kept = len(cells) - len(runner.pending_cells(cfg, out, cells))  # cell files are written whole
            print(f"truav: interrupted with {kept} of {len(cells)} cells finished and kept in {out}; run the "
                  f"same command to resume", file=sys.stderr, flush=True)
            return None
    return time.perf_counter() - t0


def _finish(out: Path, cfg, cells, write, window: int, elapsed: float) -> int:
    done = [c for c in cells if runner.cell_path(out, cfg, c).is_file()]
    if not done:
        raise UsageError(f"{out} holds no finished cells of this experiment")
    results = [runner.load_cell(runner.cell_path(out, cfg, c), c) for c in done]
    files = write(out, cfg, results, window)
    if elapsed:
        print(f"ran in {elapsed:.1f} s")
    if len(done) < len(cells):
        print(f"note: {len(cells) - len(done)} of {len(cells)} cells are not finished; tables cover the rest")
    print((out / "summary.md").read_text())
    for f in files:
        print(f"  {f}")
    return 0


def cmd_velocity(args) -> int:
    cfg, seeds, episodes, eval_episodes, window, out = _setup(args, "runs/velocity", None)
    speeds = args.speeds or (QUICK["speeds"] if args.quick else list(velocity.SPEEDS))
    cells = velocity.plan(args.schemes, speeds, seeds, episodes, eval_episodes, args.seeds_per_cell)
    elapsed = _run(args, cfg, out, cells, "velocity")
    if elapsed is None:
        return INTERRUPTED
    return _finish(out, cfg, cells, velocity.write_outputs, window, elapsed)


def cmd_scale(args) -> int:
    cfg, seeds, episodes, eval_episodes, window, out = _setup(args, "runs/scale", FULL["scale_episodes"])
    uavs = args.uavs or (QUICK["uavs"] if args.quick else list(scale.UAVS))
    vehicles = args.vehicles or (QUICK["vehicles"] if args.quick else list(scale.VEHICLES))
    cells = scale.plan(args.schemes, uavs, vehicles, args.speed, seeds, episodes, eval_episodes, args.seeds_per_cell)
    elapsed = _run(args, cfg, out, cells, "scale")
    if elapsed is None:
        return INTERRUPTED
    return _finish(out, cfg, cells, scale.write_outputs, window, elapsed)

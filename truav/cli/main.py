"""`truav`: train, evaluate and inspect TRUAV runs.

    truav train                      # the paper's run at 15 m/s: 10 seeds x 5000 x 100 steps
    truav train --speed 25 --episodes 500 --seeds 4 --out runs/quick
    truav evaluate runs/train-15mps --against random hover
    truav config show --set scenario.n_uavs=8
    truav traffic build                 # the scenario's SUMO trace, for truav train --mobility sumo
    truav experiment velocity --quick   # the paper's velocity figure (see truav/cli/experiment.py)
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from truav.analysis import policy_scenario, runio
from truav.checks import check_federated
from truav.stats import nan_mean
from truav.cli.args import (  # noqa: F401  (the number types are shared from here by the other CLIs)
    OneLineParser, UserError, non_negative_float, positive_float, positive_int, run_main, seed_int)
from truav.cli.config import (  # noqa: F401  (re-exported: the other CLIs named them from here)
    UsageError, add_config_args, add_preset_arg, config_from, parse_sets, preset_from)
from truav.config import MOBILITIES, Config, LearnerConfig, ScenarioConfig, to_toml
from truav.cli.traffic import add_traffic_parser
from truav.cli.experiment import add_experiment_parser
from truav.seeding import EVAL_SEED_OFFSET

REFERENCE_POLICIES = ("random", "hover", "patrol")
"""evaluate --against's built-in controllers (trainer.make_controller); any other name is an agent class."""

SUMMARY_METRICS = (("coverage_pct", "coverage %", 1.0), ("pdr", "PDR %", 100.0),
                   ("delay_ms", "delay ms", 1.0), ("energy_j", "energy kJ/UAV", 1e-3))


def seed_list(args) -> list[int]:
    return list(range(args.seed_start, args.seed_start + args.seeds))


def format_table(rows: dict[str, dict[str, np.ndarray]]) -> str:
    """One line per scheme: mean ± 95% interval over seeds of the summary metrics."""
    from truav.stats import mean_ci, shown
    header = f"{'scheme':<10}" + "".join(f"{label:>22}" for _, label, _ in SUMMARY_METRICS)
    lines = [header, "-" * len(header)]
    for scheme, per_seed in rows.items():
        cells = []
        for name, _, scale in SUMMARY_METRICS:
            m, h = mean_ci(per_seed[name] * scale)
            cells.append(f"{m:10.2f} ± {h:<9.2f}" if np.isfinite(h) else f"{shown(m, '10.2f')}{'':12}")
        lines.append(f"{scheme:<10}" + "".join(f"{c:>22}" for c in cells))
    return "\n".join(lines)


def paired_lines(rows: dict[str, dict[str, np.ndarray]], against: str) -> str:
    """Each other scheme's difference from ``against`` per metric, paired over seeds (the same evaluation
    seeds drive the same traffic for every scheme), with its 95% interval or why there is none."""
    from truav.stats import effect_text, paired_effect
    lines = []
    for scheme, per_seed in rows.items():
        if scheme == against:
            continue
        lines.append(f"{against} - {scheme}, paired over seeds, 95% t-interval:")
        for name, label, scale in SUMMARY_METRICS:
            e = paired_effect(per_seed[name] * scale, rows[against][name] * scale)
            lines.append(f"  {label:<16}{effect_text(e, noun='seeds')}")
    return "\n".join(lines)


def progress_bar(total: int, desc: str, quiet: bool, initial: int = 0):
    from tqdm import tqdm
    return tqdm(total=total, initial=initial, desc=desc, unit="ep", disable=quiet, dynamic_ncols=True,
                bar_format="{l_bar}{bar}| {n_fmt}/{total_fmt} env-episodes [{elapsed}<{remaining}{postfix}]")


def _compile_first(extra_kernels: list[str] = ()) -> None:
    """Compile the kernels before the progress bar (else it sits at 0 for a minute, its ETA counting the
    compiler): the shared ones once per machine (truav.analysis.warmup), ``extra_kernels`` named if they are cold."""
    from truav import kernel_cache  # here: they import numba, which `truav --help` does without
    from truav.analysis import warmup
    warmup.ensure_compiled(lambda line: print(line, flush=True))
    note = kernel_cache.cold_start_note(list(extra_kernels)) if extra_kernels else None
    if note:
        print(note, flush=True)


def run_with_progress(kind, cfg, seeds, episodes, workers, train, q, desc, quiet, start_pos=None, ckpt=None,
                      chunks=None, done=0):
    """run_parallel under a progress bar; ``done``: env-episodes a resumed run had finished before."""
    from truav.analysis.trainer import run_parallel
    with progress_bar(len(seeds) * episodes, desc, quiet, initial=done) as bar:
        def on_progress(n, live):
            bar.update(n)
            bar.set_postfix_str("cov {coverage_pct:.1f}% pdr {pdr:.3f} delay {delay_ms:.0f}ms "
                                "E {energy_j:.0f}J".format(**live), refresh=False)
        return run_parallel(kind, cfg, seeds, episodes, workers, train, q, on_progress, start_pos, ckpt, chunks)


# -- commands -----------------------------------------------------------------
def cmd_config_show(args) -> int:
    from truav.presets import DEFAULT_PRESET, preset_header
    from truav.channel_catalog import describe
    cfg = config_from(args)
    sys.stdout.write(preset_header(args.preset or DEFAULT_PRESET) + describe() + to_toml(cfg))
    return 0


def cmd_train(args) -> int:
    from truav.analysis.plots import convergence_figure
    extra: dict[str, dict[str, Any]] = {}
    if args.speed is not None:
        extra["scenario"] = {"uav_speed_mps": args.speed}
    if args.episodes is not None:
        extra["learner"] = {"episodes": args.episodes}
    if args.mobility is not None:
        extra.setdefault("scenario", {})["mobility"] = args.mobility
    cfg = config_from(args, extra)
    if cfg.scenario.mobility == "sumo":  # one line naming what to install, before anything starts
        from truav.analysis import sumo_traffic
        sumo_traffic.sumo_home()
    agent_cls, unpicklable = None, None
    if args.agent is not None:  # an agents.api class: found and checked before anything starts
        from truav.analysis import agent_loader
        if args.scheme is not None:
            raise UsageError(f"--agent {args.agent} and --scheme {args.scheme} exclude each other")
        agent_cls = agent_loader.load(args.agent, cfg)
        args.scheme = agent_loader.AGENT_KIND_PREFIX + args.agent
        unpicklable = agent_loader.checkpoint_problem(agent_cls, cfg)
        if unpicklable:
            if args.resume:
                raise UsageError(f"--resume: --agent {args.agent}: {unpicklable}, so its training keeps no "
                                 f"checkpoint; train it again with --force")
            print(f"note: --agent {args.agent}: {unpicklable}; this training keeps no checkpoint and cannot resume",
                  file=sys.stderr)
    args.scheme = args.scheme or "truav"
    check_federated(cfg, args.scheme, learns=True)
    seeds = seed_list(args)
    from agents.state import check_qtable_memory  # before anything is allocated or written
    check_qtable_memory(cfg, len(seeds) * cfg.scenario.n_uavs, f"{len(seeds)} seed(s) x {cfg.scenario.n_uavs} UAV(s)")
    from truav.analysis.trainer import Checkpointing, resumable, split
    scheme = args.scheme
    checkpointed = resumable(scheme) and not unpicklable
    episodes = cfg.learner.episodes
    out_arg = args.out if args.out is not None else f"runs/train-{cfg.scenario.uav_speed_mps:g}mps"
    chunks = _resume_chunks(args, out_arg, cfg, seeds) if args.resume else None
    if cfg.scenario.mobility == "sumo":  # built once and cached (truav traffic build), read and checked before --out
        path, _, _ = sumo_traffic.checked_trace(cfg, say=lambda line: print(line, flush=True))
        print(f"SUMO traffic: {path}", flush=True)
    if chunks is None:
        if not args.force and runio.read_resume_info(Path(out_arg)) is not None:
            raise runio.RunDirError(f"--out {out_arg}: holds an interrupted training; pass --resume to continue it, "
                                    f"--force to start afresh, or choose another --out")
        out = runio.fresh_dir(out_arg, args.force)
        runio.remove_resume_state(out)
        runio.write_config(out, cfg)
        chunks = split(seeds, min(args.workers, len(seeds)))
        if checkpointed:
            runio.write_resume_info(out, {"scheme": scheme, "seeds": seeds, "chunks": chunks})
    else:
        out = Path(out_arg)
    workers = len(chunks)
    done_before = _resumed_episodes(out, chunks) if args.resume else 0
    ckpt = None if not checkpointed else Checkpointing(
        every_s=args.checkpoint_every, save=lambda i, data: runio.write_chunk_state(out, i, data),
        load=(lambda i: runio.read_chunk_state(out, i)) if args.resume else (lambda i: None))
    print(f"{'resuming' if args.resume else 'training'} {scheme}: {len(seeds)} seeds x {episodes} episodes x "
          f"{cfg.scenario.steps_per_episode} steps at {cfg.scenario.uav_speed_mps:g} m/s"
          + (" on SUMO traffic" if cfg.scenario.mobility == "sumo" else "") + f" on {workers} worker(s) "
          f"-> {out}", flush=True)
    _compile_first(["agents/sac_kernels.py"] if scheme == "central" else [])
    t0 = time.perf_counter()
    from agents.api_controller import AgentFailure
    try:
        result = run_with_progress(scheme, cfg, seeds, episodes, workers, True, None, "train", args.quiet, ckpt=ckpt,
                                   chunks=chunks, done=done_before)
    except AgentFailure as exc:  # the class broke during the run: its one line, exit 1, its checkpoints stand
        if ckpt is None:
            print(f"truav: error: {exc}", file=sys.stderr)
        else:
            from truav.analysis.trainer import saved_episodes
            kept = min(0 if (saved := runio.read_chunk_state(out, i)) is None else saved_episodes(saved)
                       for i in range(len(chunks)))
            print(f"truav: error: {exc}; {out / runio.RESUME_DIR} keeps what was checkpointed ({kept} of {episodes} "
                  f"episodes for every seed): fix the class and run the same command with --resume", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        if ckpt is not None:  # a second Ctrl-C: the checkpoints written so far stand
            raise
        print(f"interrupted: {'--agent ' + args.agent if agent_cls else '--scheme ' + scheme} keeps no checkpoint "
              f"and cannot resume; train it again with --force",
              file=sys.stderr)
        return 130
    elapsed = time.perf_counter() - t0
    if result.stopped:
        done = len(next(iter(result.metrics.values()), []))
        if done:
            runio.write_metrics(out / runio.METRICS_FILE, seeds, result.metrics)
        print(f"interrupted: {done} of {episodes} episodes finished for every seed"
              + (f" ({out / runio.METRICS_FILE})" if done else "")
              + f"; checkpointed in {out / runio.RESUME_DIR}: the same command with --resume continues it exactly",
              file=sys.stderr)
        return 130
    runio.write_metrics(out / runio.METRICS_FILE, seeds, result.metrics)
    from truav.analysis.agent_run import AGENT_FILE, write_agent_state
    if scheme == "central":  # the actors, for `truav-swarm up --scheme central --policy RUN`
        runio.write_policy(out, seeds, result.policy, cfg)
    elif agent_cls is not None:  # its state_dicts, for `truav evaluate RUN`
        write_agent_state(out, args.agent, agent_cls.api_version, seeds, result.policy, result.uav_pos, cfg)
    else:
        runio.write_qtables(out, seeds, result.q, result.uav_pos, cfg)
    window = min(500, episodes)
    label = args.agent if agent_cls is not None else scheme
    title = {"truav": "TRUAV", "central": "centralized SAC"}.get(scheme, f"agent {label}")
    convergence_figure(result.metrics, out / runio.CONVERGENCE_FILE, window=window,
                       title=f"{title} at {cfg.scenario.uav_speed_mps:g} m/s")
    steps = (len(seeds) * episodes - done_before) * cfg.scenario.steps_per_episode  # this run's own, not the resumed
    print(f"done in {elapsed:.1f} s ({steps / elapsed:,.0f} env-steps/s"
          + (f" over the {len(seeds) * episodes - done_before:,} env-episodes after the resume)" if done_before else ")"))
    last = {k: nan_mean(v[-window:], axis=0) for k, v in result.metrics.items()}
    print(f"last {window} episodes, mean ± 95% interval over seeds:")
    print(format_table({label: last}))
    state_file = {"truav": runio.QTABLE_FILE, "central": runio.POLICY_FILE}.get(scheme, AGENT_FILE)
    for name in (runio.METRICS_FILE, state_file,
                 runio.CONVERGENCE_FILE, runio.CONFIG_FILE):
        print(f"  {out / name}")
    runio.remove_resume_state(out)  # finished: nothing to resume
    return 0


def _resume_chunks(args, out_arg: str, cfg: Config, seeds: list[int]) -> list[list[int]]:
    """--resume: the seed chunks of the interrupted training in --out, once its options are checked equal."""
    from truav.analysis.trainer import resumable
    if args.force:
        raise UsageError("--resume and --force exclude each other (continue the training in --out, or replace it)")
    if not resumable(args.scheme):
        raise UsageError(f"--resume: --scheme {args.scheme} cannot continue exactly (its SAC's torch state is not "
                         f"checkpointed); train it again with --force")
    out = Path(out_arg)
    info = runio.read_resume_info(out)
    if info is None:
        raise runio.RunDirError(f"--resume: {out} holds no interrupted training (no {runio.RESUME_DIR}/"
                                f"{runio.RESUME_FILE}); train without --resume")
    old = out / runio.CONFIG_FILE
    if not old.is_file() or old.read_text() != to_toml(cfg):
        raise runio.RunDirError(f"--resume: {out} was trained with another config (--config, --set, --speed or "
                                f"--episodes differ from {old}); give the interrupted command's options, or --force")
    if info.get("seeds") != seeds or info.get("scheme") != args.scheme:
        raise runio.RunDirError(f"--resume: {out} was trained with seeds {info.get('seeds')} and --scheme "
                                f"{info.get('scheme')}; give the interrupted command's --seeds/--seed-start/--scheme")
    chunks = info.get("chunks")
    if not (isinstance(chunks, list) and sum(chunks, []) == seeds):
        raise runio.RunDirError(f"--resume: {out / runio.RESUME_DIR / runio.RESUME_FILE} is damaged (its chunks of "
                                f"seeds do not add up to the seeds)")
    from truav.analysis.trainer import check_saved_chunk
    for index, chunk in enumerate(chunks):  # a damaged file is one line here, not a worker's traceback later
        saved = runio.read_chunk_state(out, index)
        problem = None if saved is None else check_saved_chunk(saved, len(chunk))
        if problem:
            raise runio.RunDirError(f"--resume: {out / runio.RESUME_DIR}/chunk{index}.pkl is damaged ({problem}); "
                                    f"train again with --force")
    return chunks


def _resumed_episodes(out: Path, chunks: list[list[int]]) -> int:
    """Env-episodes (seeds x episodes) the checkpoints of a resumed training had finished."""
    from truav.analysis.trainer import saved_episodes
    total = 0
    for index, chunk in enumerate(chunks):
        saved = runio.read_chunk_state(out, index)
        total += 0 if saved is None else saved_episodes(saved) * len(chunk)
    return total


def _against_kinds(names: list[str], cfg: Config, taken: str) -> dict[str, str]:
    """{label: controller kind} of evaluate's --against: a reference policy, or an agents.api class by name
    (found and checked here, before anything runs; labelled apart from ``taken``, the evaluated run's)."""
    from truav.analysis import agent_loader
    kinds = {}
    for name in names:
        if name in REFERENCE_POLICIES:
            kinds[name] = name
        else:
            agent_loader.load(name, cfg, flag="--against")
            kinds[name + " (untrained)" if name == taken else name] = agent_loader.AGENT_KIND_PREFIX + name
    return kinds


def cmd_evaluate(args) -> int:
    from truav.analysis import agent_loader
    from truav.analysis.agent_run import is_agent_run, read_agent_state
    run = Path(args.run)
    if not run.exists():  # not "its parent has no config.toml": the path the user gave
        raise runio.RunDirError(f"{args.run}: no such run directory or file (a directory `truav train` wrote, "
                                f"or its {runio.QTABLE_FILE})")
    cfg = runio.read_config(run if run.is_dir() else run.parent)
    if is_agent_run(run):  # a run of `truav train --agent NAME`: that class, with its learned state
        name, seeds, q, end_pos = read_agent_state(run)
        agent_cls = agent_loader.load(name, cfg, flag=f"{args.run}: agent")
        uavs = {v.shape[1] for v in q.values()} | ({end_pos.shape[1]} if end_pos is not None else set())
        if uavs - {cfg.scenario.n_uavs}:
            raise runio.RunDirError(f"{args.run}: its agent state holds {sorted(uavs)} UAVs, its config "
                                    f"{cfg.scenario.n_uavs}")
        agent_loader.check_state(f"{args.run}: agent {name}", agent_cls, cfg, {  # as `up --qtable` does: exit 2
            f"UAV {u}'s state of seed {s}": {k: np.array(v[b, u]) for k, v in q.items()}
            for b, s in enumerate(seeds) for u in range(cfg.scenario.n_uavs)})
        main_kind = agent_loader.AGENT_KIND_PREFIX + name
        main_label = main_kind if name in REFERENCE_POLICIES else name  # apart from --against random etc.
    else:
        seeds, q = runio.read_qtables(run)
        runio.check_qtables(run, q.shape, cfg)
        main_label, main_kind, end_pos = "truav", "truav", None
    cfg = cfg.replace(**preset_from(args))
    if args.set:  # e.g. the trained policy under another channel.model
        cfg = cfg.replace(**parse_sets(args.set))
        if main_kind == "truav":
            runio.check_qtables(run, q.shape, cfg)
    if args.speed is not None:
        cfg = cfg.replace(scenario={"uav_speed_mps": args.speed})
    from truav.analysis.agent_run import agent_file
    policy_file = runio.qtable_file(run) if main_kind == "truav" else agent_file(run)
    fit = policy_scenario.check("", args.run, policy_file, cfg, args.allow_scenario_mismatch)
    if fit.line():
        print(f"warning: {fit.line()}", flush=True)
    eval_seeds = [s + EVAL_SEED_OFFSET for s in seeds]
    workers = min(args.workers, len(seeds))
    # A persist swarm goes on from its station, as in training; a fresh random
    # deployment would put its agents in states they never visited (docs/results/reproduction.md).
    start = (end_pos if main_kind != "truav" else runio.read_uav_positions(run)) \
        if cfg.scenario.uav_start == "persist" else None
    kinds = {main_label: main_kind, **_against_kinds(list(args.against), cfg, main_label)}
    _compile_first()
    rows = {}
    from agents.api_controller import AgentFailure
    from agents.spread_agent import with_sensing  # the heuristic flies with its sensing on
    for label, kind in kinds.items():
        try:
            run_cfg = cfg if label == main_label else with_sensing(label, cfg)
            result = run_with_progress(kind, run_cfg, eval_seeds, args.episodes, workers, False,
                                       q if label == main_label else None, label, args.quiet, start)
        except AgentFailure as exc:
            print(f"truav: error: {exc}", file=sys.stderr)
            return 1
        rows[label] = {k: nan_mean(v, axis=0) for k, v in result.metrics.items()}
    print(f"greedy evaluation: {len(seeds)} seeds x {args.episodes} episodes on held-out traffic "
          f"at {cfg.scenario.uav_speed_mps:g} m/s; mean ± 95% interval over seeds"
          + ("; the swarm starts where training left it" if start is not None else ""))
    print(format_table(rows))
    if len(rows) > 1:
        print(paired_lines(rows, main_label))
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = OneLineParser(prog="truav", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True, metavar="COMMAND")

    cfg = sub.add_parser("config", help="inspect the configuration")
    cfg_sub = cfg.add_subparsers(dest="config_command", required=True, metavar="ACTION")
    show = cfg_sub.add_parser("show", help="print the effective config as TOML")
    add_config_args(show)
    show.set_defaults(func=cmd_config_show)

    tr = sub.add_parser("train", help="train TRUAV agents for many seeds (one batch per core)")
    add_config_args(tr)
    tr.add_argument("--scheme", choices=("truav", "central"),
                    help="truav (Q-tables, default) or central (the centralized SAC; writes policy.npz for "
                         "`truav-swarm up --scheme central --policy RUN`)")
    tr.add_argument("--agent", metavar="NAME",
                    help="train your own agent class instead (pkg.module:Class, or a name registered in the "
                         "entry-point group truav.agents, e.g. random, patrol; agents/api.py, "
                         "docs/how-to/your-own-agent.md); writes agent.npz")
    tr.add_argument("--speed", type=positive_float,
                    help=f"UAV speed in m/s (default: scenario.uav_speed_mps, {ScenarioConfig().uav_speed_mps:g})")
    tr.add_argument("--mobility", choices=MOBILITIES,
                    help="vehicle mobility: builtin (the grid's IDM) or sumo (a SUMO trace, built and cached on "
                         "first use; `truav traffic build`) (default: scenario.mobility, builtin)")
    tr.add_argument("--seeds", type=positive_int, default=10,
                    help="number of seeds (default %(default)s, as the paper)")
    tr.add_argument("--seed-start", type=seed_int, default=0, help="first seed (default %(default)s)")
    tr.add_argument("--episodes", type=positive_int,
                    help=f"episodes (default: learner.episodes, {LearnerConfig().episodes})")
    tr.add_argument("--workers", type=positive_int, default=os.cpu_count() or 1,
                    help="worker processes (default: all cores)")
    tr.add_argument("--out", help="output directory (default runs/train-<speed>mps)")
    tr.add_argument("--force", action="store_true", help="write into a non-empty --out")
    tr.add_argument("--resume", action="store_true",
                    help="continue the interrupted training in --out (Ctrl-C checkpoints it at the episodes' end) "
                         "exactly as if it had not stopped; same options only (scheme truav or an --agent class)")
    tr.add_argument("--checkpoint-every", type=positive_float, default=runio.CHECKPOINT_EVERY_S, metavar="SECONDS",
                    help="seconds between checkpoints of a running training (default %(default)g); Ctrl-C, "
                         "SIGTERM and SIGHUP also checkpoint, at the episode's end")
    tr.add_argument("--quiet", action="store_true", help="no progress bar")
    tr.set_defaults(func=cmd_train)

    ev = sub.add_parser("evaluate", help="run saved Q-tables (or an agent's state) greedily and print the metrics")
    ev.add_argument("run", help="run directory of 'truav train' (or its qtables.npz, or agent.npz)")
    ev.add_argument("--episodes", type=positive_int, default=20, help="episodes per seed (default %(default)s)")
    ev.add_argument("--speed", type=positive_float, help="evaluate at another UAV speed (with "
                                                         "--allow-scenario-mismatch if it was trained at another)")
    add_preset_arg(ev, "apply a scenario preset (literal or paper) on top of the run's saved config")
    ev.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="override one value of the run's saved config (repeatable), e.g. --set channel.model=al-hourani")
    ev.add_argument("--against", nargs="*", default=[], metavar="NAME",
                    help=f"also run these on the same traffic: reference policies ({', '.join(REFERENCE_POLICIES)}) "
                         f"or agent classes (pkg.module:Class or a registered name), untrained; spread is the "
                         f"decentralized heuristic, the bar a learner must clear, and claim the stronger climbing "
                         f"one, both flown with their sensing on")
    ev.add_argument("--workers", type=positive_int, default=os.cpu_count() or 1)
    policy_scenario.add_allow_arg(ev)
    ev.add_argument("--quiet", action="store_true")
    ev.set_defaults(func=cmd_evaluate)

    add_experiment_parser(sub)  # truav experiment velocity | scale
    add_traffic_parser(sub)  # truav traffic build
    from truav.cli.log import add_log_commands
    add_log_commands(sub)  # truav log record | play | report | check | recover, and truav report (an alias)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_main("truav", lambda: args.func(args))


if __name__ == "__main__":
    sys.exit(main())

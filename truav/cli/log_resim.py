"""``truav log resim FILE``: re-simulate a lock-step recording and check it bit for bit; with ``--from TICK``
branch a what-if there (recorder.resim, resim_verify, resim_branch, resim_figure).

Exit codes: 0 reproduced (or, a branch, run and compared); 1 a divergence (a branch: the recording was not
reproduced up to its tick, so nothing could be restored), or a damaged recording (recorder.mcap_guard); 2 a
user mistake or a recording that is not a lock-step TRUAV run or whose recorded settings are out of bounds
(a run name the bus refuses, a config needing more than MAX_RESIM_TABLE_BYTES of Q-tables...), in one line."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from recorder.log_copy import damage_errors, not_mcap_reason
from recorder.mcap_guard import EXIT_DAMAGED, damage_line
from truav.cli.args import non_negative_int

RESIM_HELP = "re-run a lock-step recording in process and check every observation, beacon and action bit for bit"
EXIT_OK, EXIT_DIVERGED, EXIT_USAGE = 0, 1, 2


def add_resim_parser(subparsers: Any) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "resim", help=RESIM_HELP,
        description="Re-run the world and every agent of a lock-step recording (`truav-swarm up --lockstep --record "
                    "FILE`) in process, from its recorded seed and config, with the processes' own code, and "
                    "check tick by tick that every recorded observation, beacon and action is reproduced bit for "
                    "bit (payload fields; not the envelope's time stamps and sequence numbers). Prints the first "
                    "divergence (tick, key, field, both values) and the totals; exit 1 on a divergence. With "
                    "--from TICK, branch a what-if: the run is restored at TICK (re-simulated up to it and checked "
                    "against the recording on the way), then runs on with --qtable, --greedy or --set, and its "
                    "per-episode outcome is set beside the recorded one (whatif.csv, whatif.png).",
        epilog="Exit codes: 0 reproduced (a branch: run); 1 a divergence, or a damaged recording; 2 a user mistake, "
               "a recording that is not a lock-step TRUAV run, or recorded settings out of bounds. See "
               "docs/reference/untrusted-recordings.md.")
    p.add_argument("file", metavar="FILE", help="MCAP recording of a lock-step run")
    p.add_argument("--from", dest="from_tick", type=non_negative_int, metavar="TICK",
                   help="branch a what-if at this tick (ticks count on across episodes, each episode's `done` "
                        "observation included)")
    p.add_argument("--qtable", metavar="RUN", help="branch: the agents fly this trained run's Q-tables from TICK on")
    p.add_argument("--qtable-index", type=non_negative_int, default=0, metavar="N",
                   help="branch: which seed's tables of --qtable (default 0)")
    p.add_argument("--greedy", action="store_true", help="branch: act greedily and learn nothing from TICK on")
    p.add_argument("--set", action="append", default=[], metavar="learner.KEY=VALUE",
                   help="branch: change a learner setting from TICK on (rates, reward weights, geofence; the "
                        "exploration schedule from the next episode; repeatable)")
    p.add_argument("--no-snapshots", action="store_true",
                   help="branch: restore by re-simulating from tick 0 even when the recording holds state "
                        "snapshots (by default from the latest one at or before TICK)")
    p.add_argument("--out", metavar="DIR", help="branch: where whatif.csv and whatif.png go (default: "
                                                "<FILE stem>_whatif next to FILE)")
    p.add_argument("--agent", metavar="NAME",
                   help="a run flown by an agent API class (`up --agent NAME`): re-simulating it imports and runs "
                        "that class, so it is done only when NAME is given and equals the recorded one")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def _fail(message: str, code: int = EXIT_USAGE) -> int:
    print(f"truav: error: {message}", file=sys.stderr)
    return code


def cmd_resim(args: argparse.Namespace) -> int:
    from recorder.resim import Resimulation, load_run, recorded_overrides, start_tables
    from recorder.resim_branch import branch_config
    from recorder.resim_verify import first_tick
    from truav.checks import check_out_dir
    from truav.cli.config import parse_sets
    from truav.errors import UserError

    problem = not_mcap_reason(args.file)
    if problem:
        return _fail(problem)
    branch = args.from_tick is not None
    changes = [flag for flag, given in (("--qtable", args.qtable), ("--greedy", args.greedy), ("--set", args.set),
                                        ("--out", args.out), ("--no-snapshots", args.no_snapshots)) if given]
    if changes and not branch:
        return _fail(f"{changes[0]} changes a what-if branch: give --from TICK")
    try:
        rec = load_run(args.file)
        first = first_tick(args.file, rec.run)
        if first is None:  # else "reproduced": of nothing
            raise UserError(f"{args.file}: holds no observation, beacon or action of run {rec.run!r} (its run "
                            f"stopped before tick 0, or the recorder died before its first flush); nothing to "
                            f"re-simulate")
        if first > 0 and not branch:  # else every earlier tick "diverges": not recorded
            raise UserError(f"{args.file}: holds nothing of ticks 0-{first - 1} (a cut of its run): a "
                            f"re-simulation checks every tick from 0; check the recording it was cut from, or "
                            f"branch with --from TICK (restored from a state snapshot it holds)")
        n = rec.cfg.scenario.n_uavs
        agent_cls = _agent_class(args, rec, branch)
        if agent_cls is not None and rec.qtable:  # its agents started from a run of `truav train --agent`
            from truav.analysis.agent_run import agent_start_states
            starts = agent_start_states(rec.qtable, rec.agent, n, rec.qtable_index)
            from truav.analysis.agent_loader import check_state  # refused: exit 2, as in up and evaluate
            check_state(f"{args.file}: its start {rec.qtable}", agent_cls, rec.cfg,
                        {f"UAV {u}'s state": s for u, s in enumerate(starts)})
        else:
            starts = start_tables(rec.qtable, rec.qtable_index, n)
        sim = Resimulation(rec.cfg, rec.seed, rec.episodes, starts, train=not rec.greedy, agent_cls=agent_cls,
                           overrides=recorded_overrides(args.file, rec.run, n))
        if branch:
            if args.from_tick >= sim.total_ticks:
                raise UserError(f"--from {args.from_tick}: the run has ticks 0-{sim.total_ticks - 1}")
            tables = start_tables(args.qtable, args.qtable_index, n) if args.qtable else None
            learner = branch_config(rec.cfg, parse_sets(args.set)) if args.set else None
            out = check_out_dir("--out", args.out or str(Path(args.file).with_name(Path(args.file).stem + "_whatif")))
    except UserError as exc:
        return _fail(str(exc))
    except damage_errors() as exc:
        return _fail(damage_line(args.file, exc), EXIT_DAMAGED)
    print(f"{args.file}: run {rec.run!r}, seed {rec.seed}, {n} UAVs, {rec.episodes} episode(s) of "
          f"{rec.cfg.scenario.steps_per_episode} steps, lock-step"
          f"{', from ' + rec.qtable if rec.qtable else ''}{', greedy' if rec.greedy else ''}"
          f"{', agent class ' + rec.agent if rec.agent else ''}", flush=True)
    steered = sum(len(v) for v in sim.override_events.values())
    if steered:
        print(f"overrides: {steered} start(s) and end(s) of UAVs steered from outside (the recording's fault/override), "
              f"applied at their ticks", flush=True)
    bar = _progress(sim.total_ticks, args.quiet)
    try:
        if branch:
            return _branch(args, rec, sim, out, bar, tables, learner)
        return _verify(args, rec, sim, bar)
    except UserError as exc:  # a recorded snapshot that does not fit its run
        return _fail(str(exc))
    except damage_errors() as exc:
        return _fail(damage_line(args.file, exc), EXIT_DAMAGED)
    finally:
        bar.close()


def _progress(total: int, quiet: bool):
    from tqdm import tqdm
    return tqdm(total=total, desc="re-simulating", unit="tick", disable=quiet, dynamic_ncols=True, file=sys.stderr,
                bar_format="{l_bar}{bar}| {n_fmt}/{total_fmt} ticks [{elapsed}<{remaining}{postfix}]")


def _on_round(bar, word: str = "divergent"):
    diverged = [0]

    def on_round(rnd, divergent: int) -> None:
        bar.update(1)
        if divergent:
            diverged[0] += divergent
            bar.set_postfix_str(f"{diverged[0]} {word}", refresh=False)
    return on_round


def _agent_class(args, rec, branch: bool):
    """The agent API class of an `up --agent NAME` recording, loaded only when --agent names it (a recording
    from elsewhere must not pick the code this command runs); None for TRUAV's own agents."""
    from truav.analysis import agent_loader
    from truav.errors import UserError
    if rec.agent is None:
        if args.agent is not None:
            raise UserError(f"--agent {args.agent}: {args.file} was flown by TRUAV's own agents; leave --agent out")
        return None
    if args.agent is None:
        raise UserError(f"{args.file}: flown by the agent class {rec.agent[:100]!r}; re-simulating it imports and "
                        f"runs that class: give --agent {rec.agent[:100]} to do so")
    if args.agent != rec.agent:  # another name of the same class (entry point, module path) is that class
        given = agent_loader.resolve(args.agent)
        if not agent_loader.same_class(rec.agent, given):
            raise UserError(f"--agent {args.agent}: {args.file} was flown by {rec.agent[:100]!r} (as recorded), and "
                            f"--agent {args.agent} is {agent_loader.class_path(given)}, another class (give --agent "
                            f"{rec.agent[:100]} to re-simulate it)")
    if branch:
        raise UserError("--from: what-if branches restore TRUAV's agents from state snapshots; an agent class's "
                        "run is re-simulated from tick 0 only")
    return agent_loader.load(args.agent, rec.cfg)


def _verify(args, rec, sim, bar) -> int:
    from recorder.resim_verify import verify

    result = verify(args.file, rec.run, sim, on_round=_on_round(bar), check_snapshots=not sim.api)
    bar.close()
    print("\n".join(result.summary_lines()))
    if sim.api:
        errors = sum(a.errors for a in sim.agents)
        print(f"recorded state snapshots: not checked (an agent class's state is its own); the class failed "
              f"{errors} call(s) in the re-simulation (each a hovered tick, as in the run)")
    if result.exact:
        print("result: reproduced (every recorded observation, beacon and action, bit for bit)")
        return EXIT_OK
    print(f"result: NOT reproduced ({result.divergent_messages} divergent message(s)"
          + (f", {result.leftover} recorded message(s) never compared" if result.leftover else "")
          + (f", {result.snapshots_differing} recorded state snapshot(s) differ" if result.snapshots_differing
             else "") + ")")
    return EXIT_DIVERGED


def _branch(args, rec, sim, out: Path, bar, tables, learner) -> int:
    from recorder.resim_branch import run_branch
    from recorder.resim_figure import whatif_figure, write_csv
    from truav.checks import make_dir

    result = run_branch(args.file, rec.run, rec, sim, args.from_tick, tables=tables, greedy=args.greedy,
                        learner=learner, on_round=_on_round(bar, "differing"), snapshots=not args.no_snapshots,
                        on_restore=bar.update)
    bar.close()
    restored = result.restored
    if restored.divergent_messages or restored.recording_ended or restored.snapshots_differing:
        print("\n".join(restored.summary_lines()))
        why = (f"diverged before it ({restored.first.format()})" if restored.first is not None
               else "the recording ends before it")
        return _fail(f"cannot branch at tick {args.from_tick}: the re-simulation of the recording {why}", EXIT_DIVERGED)
    what = ", ".join(result.changes) or "nothing changed (the recorded policy)"
    start = 0 if result.snapshot_tick is None else result.snapshot_tick
    if result.snapshot_tick is not None:
        how = f"from the recording's snapshot of tick {start}"
    else:
        how = "from tick 0 (" + ("--no-snapshots" if args.no_snapshots else
                                 f"the recording holds no snapshot at or before tick {result.from_tick}") + ")"
    span = f"re-simulating ticks {start}-{result.from_tick - 1}" if result.from_tick > start else "nothing to re-run"
    print(f"restored at tick {result.from_tick} (episode {result.from_episode}) {how}, {span}, each tick checked "
          f"against the recording; branch: {what}")
    print("\n".join(result.table_lines()))
    if result.departed is None and result.after.exact:
        print(f"the branch equals the recorded run from tick {result.from_tick} on (every message, bit for bit)")
    else:
        first = result.departed.format() if result.departed is not None else "recorded messages left over"
        print(f"the branch departs from the recorded run at {first}; "
              f"{result.after.divergent_messages} of {sum(result.after.compared.values())} messages after the "
              f"branch differ")
    make_dir("--out", out)
    write_csv(result, out / "whatif.csv")
    title = f"{Path(args.file).name}: branch at tick {result.from_tick} ({what})"
    whatif_figure(result, out / "whatif.png", title)
    print(f"wrote {out / 'whatif.csv'} and {out / 'whatif.png'}")
    return EXIT_OK


__all__ = ["RESIM_HELP", "add_resim_parser", "cmd_resim"]

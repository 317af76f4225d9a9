"""`truav-swarm up|chaos`: start a whole swarm (router, world, agents, recorder) under a supervisor.

Every flag and file is checked here, before anything starts (:func:`swarm_options`); then
truav.swarm.supervisor runs the swarm (up) or truav.swarm.chaos runs it twice / under a nemesis.
"""

from __future__ import annotations

import argparse
import math
import re

from agents.process.agent_options import AgentOptions
from truav.analysis import policy_scenario
from truav.bus.transport import DEFAULT_ENDPOINT
from truav.checks import check_endpoint, check_federated, check_out_dir, check_out_file
from truav.cli.args import add_options, non_negative_int, positive_float, positive_int, tcp_port
from truav.cli.config import UsageError, parse_sets
from truav.cli.experiment_executor import check_ray_address
from truav.config import MOBILITIES
from truav.faults import NODE
from truav.lifecycle import DEFAULT_ROUTER_TIMEOUT_S
from truav.nemesis import NEMESES
from truav.swarm import supervisor
from truav.swarm.checks import (check_agent_start, check_beacon_cell, check_central_sizes, check_plan, check_policy, check_qtable,
                                check_scheme_flags)
from truav.cli.swarm_common import (add_command_hold_arg, add_geo_origin_arg, add_lockstep_args, add_policy_args,
                                    add_scenario_args, add_scheme_arg, check_agent_scheme, lockstep_wait,
                                    resolve_scheme, scenario_from)
from recorder.record_modes import RecordModes
from truav.analysis.agent_loader import AGENT_KIND_PREFIX
from truav.cli.args import options_from
from truav.errors import UserError
from truav.swarm.chaos_time import CHAOS_MAX_MISSED_SHARE, PLAN_EPISODES
from truav.swarm.external import DEFAULT_EXTERNAL_WAIT_S, check_external
from truav.swarm.healing import DEFAULT_RESTART_LIMIT, DEFAULT_RESTART_POLICY, RESTART_POLICIES
from truav.swarm.outdir import OutDirError, check_swarm_dir
from truav.swarm.supervisor import SwarmOptions
from truav.swarm.swarm_options import DEMO_AGENT, DEMO_SCHEME, SENSING_AGENTS, with_agent_sensing
from agents.spread_agent import SENSE_RANGE_M
from truav.swarm.references import HEURISTIC
from world.process.world_options import WorldOptions

RAY_PORT = 7447
"""--ray-port's default: each node's router on the port a lone router uses."""

MAX_AGENTS = 50
"""Agent processes `up` and `chaos` start without --force-agents (--agents-per-process K hosts K agents in
one). On the 2-core reference machine, quiet, all-to-all at 10 Hz with one process per agent, 20 agents
missed no action and 50 missed 0.85% (docs/results/benchmarks.md); past 50 processes the swarm is no
longer real time there, and hundreds of processes can load the machine before anything is printed. 100
agents keep up hosted 10 per process with --share-beacons."""


def swarm_options(args):
    """The scenario and options of `up`/`chaos`, every flag and file checked: nothing has started yet."""
    sets = parse_sets(args.set).get("scenario", {})
    mobility = getattr(args, "mobility", None)  # `up` only
    for flag, key, value in (("--agents", "n_uavs", args.agents), ("--steps", "steps_per_episode", args.steps),
                             ("--mobility", "mobility", mobility)):
        if value is not None and key in sets and sets[key] != value:
            raise UsageError(f"{flag} {value} contradicts --set scenario.{key}={sets[key]}; give one of them")
    cfg = scenario_from(args)
    if args.agents is not None:
        cfg = cfg.replace(scenario={"n_uavs": args.agents})
    if args.steps is not None:
        cfg = cfg.replace(scenario={"steps_per_episode": args.steps})
    if mobility is not None:
        cfg = cfg.replace(scenario={"mobility": mobility})
    if cfg.scenario.mobility == "sumo":  # one line naming what to install, before anything starts
        from truav.analysis import sumo_traffic
        sumo_traffic.sumo_home()
    defaulted = args.scheme is None and args.agent is None
    resolve_scheme(args, args.default_scheme)  # up: the demo's policy (DEMO_SCHEME); chaos: truav
    if defaulted and args.qtable is not None and args.scheme != "truav":
        from truav.analysis.agent_run import is_agent_run
        if not is_agent_run(args.qtable):  # the old habit: a `truav train` run, flown by the Q-learners
            raise UsageError(f"--qtable {args.qtable}: not a run of `truav train --agent NAME`; a `truav train` run's "
                             f"Q-tables fly with --scheme truav (this is --scheme {args.scheme}, up's default): "
                             f"add --scheme truav")
    cfg = with_agent_sensing(args.scheme, cfg)
    check_agent_scheme(args, cfg)
    n = cfg.scenario.n_uavs
    external = tuple(getattr(args, "external", None) or ())  # `up` only: chaos runs the swarm twice
    processes = -(-n // args.agents_per_process)
    if processes > MAX_AGENTS and not args.force_agents:
        raise UsageError(f"--agents {n}" + ("" if args.agents is not None else " (from scenario.n_uavs)")
                         + (f" at --agents-per-process {args.agents_per_process}" if args.agents_per_process > 1 else "")
                         + f": more than {MAX_AGENTS} agent processes is past what the reference machine runs in "
                         f"real time (see MAX_AGENTS in truav/cli/swarm_up.py); host more agents per process "
                         f"(--agents-per-process), or add --force-agents to start them anyway")
    if len(args.listen) > 1:
        raise UsageError(f"-l/--listen: the swarm's router listens on one endpoint, got {len(args.listen)}")
    for ep in args.listen:
        check_endpoint("-l/--listen", ep, tcp_only=True)  # the supervisor waits for the router's TCP port
    if args.out is not None:
        check_out_dir("--out", args.out)
    if args.record is not None:
        check_out_file("--record", args.record)
    check_scheme_flags(args)
    check_federated(cfg, args.scheme, learns=not getattr(args, "greedy", False))
    from agents.state import check_qtable_memory  # each agent process holds its UAV's table
    check_qtable_memory(cfg, cfg.scenario.n_uavs, f"{cfg.scenario.n_uavs} UAV(s)")
    fit = None
    if args.qtable is not None and args.scheme.startswith(AGENT_KIND_PREFIX):  # a run of `truav train --agent`
        fit = check_agent_start("--qtable", args.qtable, args.scheme[len(AGENT_KIND_PREFIX):], cfg,
                                allow_mismatch=args.allow_scenario_mismatch)
    elif args.qtable is not None:
        fit = check_qtable("--qtable", args.qtable, cfg, allow_mismatch=args.allow_scenario_mismatch)
    if args.policy is not None:
        fit = check_policy("--policy", args.policy, cfg, args.policy_index, args.allow_scenario_mismatch)
    if fit is not None and fit.line():  # said now, and again in the summary
        print(f"warning: {fit.line()}", flush=True)
    if args.scheme == "central":
        check_central_sizes(cfg)
    plan = check_plan("--fault-plan", args.fault_plan, n, args.scheme) if args.fault_plan is not None else None
    beacon_every = 1
    if args.beacon_hz is not None:
        ticks = args.rate / args.beacon_hz
        if abs(ticks - round(ticks)) > 1e-6 or round(ticks) < 1:
            raise UsageError(f"--beacon-hz {args.beacon_hz:g}: must divide --rate {args.rate:g} into a whole number "
                             f"of ticks (e.g. 1 at 10 Hz: every 10th tick)")
        beacon_every = int(round(ticks))
    check_beacon_cell(args.beacon_cell, cfg)
    if args.scheme != "truav" and (args.beacon_hz is not None or args.beacon_cell is not None):
        raise UsageError(f"{'--beacon-hz' if args.beacon_hz is not None else '--beacon-cell'}: only --scheme truav "
                         f"sends a beacon every tick (this is --scheme {args.scheme})")
    if args.lockstep and (args.beacon_hz is not None or args.beacon_cell is not None):
        raise UsageError(f"{'--beacon-hz' if args.beacon_hz is not None else '--beacon-cell'}: lock-step waits for "
                         f"every live peer's beacon of each tick; beacon rate and cells are for real time only")
    if args.share_beacons and args.agents_per_process == 1:
        raise UsageError("--share-beacons: shares one beacon subscription among the agents of a process; "
                         "give --agents-per-process K > 1 too")
    if args.snapshot_every != WorldOptions.snapshot_every and not (args.lockstep and args.record):
        raise UsageError(f"--snapshot-every {args.snapshot_every}: snapshots are taken in recorded lock-step runs "
                         f"only; add --lockstep and --record FILE, or drop it")
    if args.batch_beacons and (args.agents_per_process == 1 or not args.lockstep or args.scheme != "truav"):
        raise UsageError("--batch-beacons: sends the beacons of a process's agents of a tick as one message; "
                         "only with --lockstep, --scheme truav and --agents-per-process K > 1")
    check_external(external, n, args, plan)
    external_wait = getattr(args, "external_wait", None)
    if external_wait is not None and not external:
        raise UsageError(f"--external-wait {external_wait:g}: only --external UAVs are waited for; add --external "
                         f"IDS or drop it")
    if args.agents_per_process > 1 and plan is not None:
        kinds = {f.kind for f in plan.faults if f.params.get("target") != NODE} & {"crash", "freeze"}  # a node: all
        if kinds:
            raise UsageError(f"--agents-per-process {args.agents_per_process}: the fault plan {args.fault_plan} "
                             f"{' and '.join(sorted(kinds))}es single agent processes; use 1 agent per process")
    opts = SwarmOptions(run=args.run, seed=args.seed, episodes=args.episodes, lockstep=args.lockstep,
                        lockstep_wait_s=lockstep_wait(args), rate_hz=args.rate, record=args.record, qtable=args.qtable,
                        greedy=args.greedy, policy_fit=fit.as_json() if fit is not None else None,
                        out=args.out, listen=args.listen[0] if args.listen else None,
                        plot=not args.no_plot, quiet=args.quiet, wait_agents_s=args.wait_agents,
                        fault_plan=args.fault_plan, plan=plan, foxglove_port=getattr(args, "foxglove", None),
                        geo_origin=args.geo_origin, verbose=args.verbose, resume=args.resume, force=args.force,
                        max_missed_share=args.max_missed, tolerate_agent_errors=args.tolerate_agent_errors,
                        router_timeout_s=args.router_timeout,
                        secure=args.secure, scheme=args.scheme, policy=args.policy, policy_index=args.policy_index,
                        command_hold_s=args.command_hold, beacon_every=beacon_every, beacon_cell_m=args.beacon_cell,
                        beacon_slots=args.beacon_slots, agents_per_process=args.agents_per_process,
                        share_beacons=args.share_beacons, batch_beacons=args.batch_beacons,
                        snapshot_every=args.snapshot_every,
                        restart=args.restart, restart_limit=args.restart_limit, external=external,
                        external_wait_s=DEFAULT_EXTERNAL_WAIT_S if external_wait is None else external_wait,
                        references=not getattr(args, "no_references", False))
    if cfg.scenario.mobility == "sumo":  # every flag checked: the trace the world replays, built once and cached
        try:  # a mistake in --out is told before the trace is built (minutes the first time), not after
            check_swarm_dir(opts.out_dir, resume=opts.resume, force=opts.force)
        except OutDirError as exc:
            raise UsageError(str(exc)) from None
        path, _, _ = sumo_traffic.checked_trace(cfg, say=lambda line: None if args.quiet else print(line, flush=True))
        if not args.quiet:
            print(f"SUMO traffic: {path}", flush=True)
    return cfg, opts




def uav_ids(text: str) -> tuple[int, ...]:
    """--external: ``2`` or ``2,5``, UAV ids, each once (the range is checked once the scenario is known)."""
    ids = []
    for part in text.split(","):
        part = part.strip()
        if not part.isdigit():
            raise argparse.ArgumentTypeError(f"expected UAV ids such as 2 or 2,5, got {text!r}")
        ids.append(int(part))
    twice = sorted({i for i in ids if ids.count(i) > 1})
    if twice:
        raise argparse.ArgumentTypeError(f"UAV id(s) {', '.join(map(str, twice))} given twice in {text!r}")
    return tuple(ids)


def duration_s(text: str) -> float:
    """A run's length: seconds, or a number with s, m or h (90, 90s, 10m, 1h)."""
    m = re.fullmatch(r"\s*(\d+(?:\.\d*)?)\s*([smh]?)\s*", text)
    if not m or float(m.group(1)) <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive duration such as 90s, 10m or 1h, got {text!r}")
    return float(m.group(1)) * {"": 1, "s": 1, "m": 60, "h": 3600}[m.group(2)]


def cmd_chaos(args) -> int:
    from truav.swarm import chaos  # here: it loads matplotlib
    if args.fault_plan is not None:  # one plan per chaos run: the faulted half flies --plan
        raise UsageError("--fault-plan: chaos takes its plan from --plan (the baseline run has none); "
                         "drop --fault-plan")
    if (args.plan is None) == (args.nemesis is None):
        raise UsageError("--plan FILE or --nemesis random: give one of them")
    if args.nemesis is None:
        for flag, value in (("--duration", args.duration),):
            if value is not None:
                raise UsageError(f"{flag}: only with --nemesis (a --plan run lasts --episodes)")
        args.episodes = PLAN_EPISODES if args.episodes is None else args.episodes
    else:
        if args.duration is None:
            raise UsageError("--nemesis: give --duration (e.g. 10m): the schedule is drawn for the run's length")
        if args.episodes is not None:
            raise UsageError("--episodes: --nemesis sets it from --duration; give one of them")
        if args.lockstep:
            raise UsageError("--lockstep: the nemesis schedules faults in seconds of real time; lock-step ticks "
                             "are not paced (use --plan with a plan of your own)")
        if args.agents_per_process != 1:
            raise UsageError(f"--agents-per-process {args.agents_per_process}: the nemesis crashes and pauses single "
                             f"agent processes; use 1 agent per process")
        if args.resume:
            raise UsageError("--resume: a nemesis run starts afresh (re-run its plan with --plan instead)")
        args.episodes = 1  # replaced below, once the episode length is known
    cfg, opts = swarm_options(args)
    if args.nemesis is not None:
        opts.episodes = max(1, math.ceil(args.duration * opts.rate_hz / cfg.scenario.steps_per_episode))
        return chaos.run_nemesis(cfg, opts, args.nemesis, args.duration)
    plan = check_plan("--plan", args.plan, cfg.scenario.n_uavs, args.scheme)
    return chaos.run_chaos(cfg, opts, args.plan, plan)


def cmd_up(args) -> int:
    if args.ray is None:
        if args.ray_port != RAY_PORT:
            raise UsageError(f"--ray-port {args.ray_port}: only with --ray ADDRESS")
    else:
        check_ray_address(args.ray, "--ray")  # ray.init would wait minutes for a head that is not there
        if args.listen:  # the plan sets each node's endpoint
            raise UsageError("-l/--listen: not with --ray (each node's router endpoint comes from --ray-port)")
        if args.secure and (args.batch_beacons or getattr(args, "external", None)):
            raise UsageError(f"{'--batch-beacons' if args.batch_beacons else '--external'}: not with --ray --secure "
                             "(the nodes' credentials are made for single-UAV beacons and agents the swarm runs)")
    cfg, opts = swarm_options(args)
    opts.record_modes = record_modes(args)
    if args.ray is None:
        return supervisor.run_swarm(cfg, opts)
    try:  # only here: the single-host `up` does not load Ray
        from truav.swarm import ray_swarm
    except ImportError:
        raise UsageError("--ray: Ray is not installed; install TRUAV's ray extra") from None
    try:
        return ray_swarm.run_on_ray(cfg, opts, args.ray, args.ray_port)
    except ray_swarm.PlanError as exc:
        raise UsageError(str(exc)) from None


def record_modes(args) -> RecordModes:
    """`up`'s split or snapshot flags (declared in RecordModes), checked; they need --record."""
    modes = options_from(RecordModes, args)
    if modes != RecordModes() and args.record is None:
        given = next(f for f in ("--split-size", "--split-duration", "--split-on-command", "--snapshot",
                                 "--snapshot-max-mb") if getattr(args, f.lstrip("-").replace("-", "_")) not in
                     (None, False, RecordModes.snapshot_max_mb))
        raise UsageError(f"{given}: lays out the recording's files; give --record FILE too")
    try:
        return modes.validate()
    except UserError as exc:
        raise UsageError(str(exc)) from None


def add_up_args(up: argparse.ArgumentParser, default_scheme: str, default_help: str) -> None:
    add_scenario_args(up)
    add_scheme_arg(up, None, default_help)
    up.set_defaults(default_scheme=default_scheme)
    up.add_argument("--agent", metavar="NAME",
                    help="fly your own agent class (pkg.module:Class or a name registered in the entry-point group "
                         "truav.agents; docs/how-to/your-own-agent.md), one per UAV agent process; "
                         f"{', '.join(SENSING_AGENTS[:-1])} and {SENSING_AGENTS[-1]} fly with their sensing on (learner.sense_range_m "
                         f"{SENSE_RANGE_M:g}) unless --set gives another, ppo-disc with learner.sense_disc on too "
                         "(it observes the densest sensed disc)")
    add_policy_args(up)
    add_command_hold_arg(up)
    up.add_argument("--agents", type=positive_int,
                    help=f"number of UAV agents (default scenario.n_uavs, 5; at most {MAX_AGENTS} without --force-agents)")
    up.add_argument("--force-agents", action="store_true",
                    help=f"start more than {MAX_AGENTS} agent processes (not real time on a 2-core machine)")
    up.add_argument("--episodes", type=positive_int, default=2, help="episodes before the swarm stops (default 2)")
    up.add_argument("--steps", type=positive_int, help="steps per episode (default scenario.steps_per_episode, 100)")
    up.add_argument("--mobility", choices=MOBILITIES,
                    help="vehicle mobility: builtin (the grid's IDM) or sumo (the world replays a SUMO trace, built "
                         "and cached first; `truav traffic build`) (default: scenario.mobility, builtin)")
    add_lockstep_args(up, "the world waits for every live agent each tick")
    up.add_argument("--rate", type=positive_float, default=10.0, help="real-time tick rate in Hz (default 10)")
    up.add_argument("--record", metavar="FILE", help="record every message to this MCAP file")
    up.add_argument("--qtable", metavar="RUN", help="start agents from a trained run (truav train output; with "
                                                    "--agent NAME, a run of truav train --agent NAME)")
    up.add_argument("--greedy", action="store_true", help="agents act greedily and do not learn")
    policy_scenario.add_allow_arg(up)
    up.add_argument("--out", help="directory for stats, checkpoints and the picture (default runs/swarm-<run>)")
    up.add_argument("-l", "--listen", action="append", default=[], metavar="ENDPOINT",
                    help=f"router endpoint (default {DEFAULT_ENDPOINT} if that port is free, else a free loopback port)")
    up.add_argument("--resume", action="store_true",
                    help="continue the run in --out (agents resume from its checkpoints; same scenario only)")
    up.add_argument("--force", action="store_true",
                    help="delete an earlier run's files in --out (and overwrite --record) instead of refusing")
    add_options(up, WorldOptions, ["max_missed_share", "snapshot_every"])
    add_options(up, SwarmOptions, ["tolerate_agent_errors"])
    up.add_argument("--router-timeout", type=positive_float, default=DEFAULT_ROUTER_TIMEOUT_S, metavar="S",
                    help=f"world and agents stop this long after losing their router (default {DEFAULT_ROUTER_TIMEOUT_S:g})")
    up.add_argument("-v", "--verbose", action="store_true",
                    help="debug lines in every process's log, and each process's start (PID, log file) on the console")
    up.add_argument("--wait-agents", type=positive_float, default=60.0,
                    help="seconds the world waits for all agents to join before the first tick (default 60)")
    up.add_argument("--fault-plan", metavar="FILE", help="inject the faults of this plan (see deploy/plans/)")
    up.add_argument("--secure", action="store_true",
                    help="lock the bus: a fresh CA and one certificate per component in <out>/creds, mutual TLS, "
                         "and the router's access control (see `truav-swarm acl explain`); with --ray, each node's credentials made "
                         "in memory and handed to that node only, in a private directory of its own")
    up.add_argument("--beacon-hz", type=positive_float, metavar="HZ",
                    help="real time: beacons at this rate instead of every tick (1: the Remote ID rate; must divide "
                         "--rate), offset by id")
    up.add_argument("--beacon-cell", type=positive_float, metavar="M",
                    help="real time: range-limited beacons under map cells of M metres; each agent hears only the "
                         "cells within range of it, and decides as with all beacons (agents/beacon_cells.py)")
    add_options(up, AgentOptions, ["beacon_slots"])
    up.add_argument("--agents-per-process", type=positive_int, default=1, metavar="K",
                    help="host K agents per OS process, each with its own session, identity and files (default 1)")
    up.add_argument("--share-beacons", action="store_true",
                    help="with --agents-per-process K > 1: each agent process subscribes to beacons once for its K "
                         "agents (each still checks, filters and counts its own)")
    up.add_argument("--batch-beacons", action="store_true",
                    help="lock-step, with --agents-per-process K > 1: each agent process sends its K agents' beacons "
                         "of a tick as one message (each beacon still filtered per link and checked as if sent alone)")
    up.add_argument("--restart", choices=RESTART_POLICIES, default=DEFAULT_RESTART_POLICY,
                    help="on-failure (default): restart an agent or the controller that dies on its own, from its "
                         "checkpoint, after a backoff, and a dead router on its endpoint; never: leave them down "
                         "(truav/swarm/healing.py; in lock-step a restart makes the run inexact, and the summary says so)")
    up.add_argument("--restart-limit", type=non_negative_int, default=DEFAULT_RESTART_LIMIT, metavar="N",
                    help=f"restarts of one process before it is left down and the run fails (default "
                         f"{DEFAULT_RESTART_LIMIT})")
    up.add_argument("--no-plot", action="store_true", help="skip the summary picture")
    up.add_argument("--no-references", action="store_true",
                    help=f"skip the references at the end (hover, the heuristic {HEURISTIC} with its sensing, and patrol "
                         "flown in process on the same scenario, seed and episodes, beside the run's coverage and "
                         "PDR; about 3 s on a quiet 2-core machine)")
    up.add_argument("--quiet", action="store_true", help="no live status table")
    up.add_argument("--foxglove", type=tcp_port, nargs="?", const=8765, metavar="PORT",
                    help="serve the run live to the Foxglove app on ws://127.0.0.1:PORT (default 8765)")
    add_geo_origin_arg(up)




def add_up_commands(sub) -> None:
    """The `up` and `chaos` subcommands."""
    up = sub.add_parser("up", help="start router, world, agents (and recorder); live status; summary at the end")
    add_up_args(up, DEMO_SCHEME, f"{DEMO_SCHEME}, the learned decentralized policy {DEMO_AGENT} "
                                 f"with its sensing on, as the demo flies it; --scheme truav learns from scratch")
    up.add_argument("--external", type=uav_ids, metavar="IDS",
                    help="leave these UAVs (e.g. 2 or 2,5) to your own agent: up starts everything else, prints the "
                         "command that flies each with examples/outside_agent.py (endpoint, credentials under "
                         "--secure) and waits for its liveliness token before tick 0 (--scheme truav; "
                         "truav/swarm/external.py)")
    up.add_argument("--external-wait", type=positive_float, metavar="S",
                    help=f"seconds to wait for the --external UAVs to join before the run fails "
                         f"(default {DEFAULT_EXTERNAL_WAIT_S:g})")
    ray = up.add_argument_group("on a Ray cluster (the ray extra; docs/how-to/ray-cluster.md)")
    ray.add_argument("--ray", metavar="ADDRESS",
                     help="place the swarm on the nodes of this Ray cluster (auto: the one this machine is in): one "
                          "router per node linked to this node's, the world and recorder here, the agent processes "
                          "spread over the nodes, each connected to its node's router (truav/swarm/ray_plan.py)")
    ray.add_argument("--ray-port", type=tcp_port, default=RAY_PORT, metavar="PORT",
                     help=f"--ray: the TCP port of each node's router (nodes sharing an address: the next ports) "
                          f"(default {RAY_PORT})")
    add_options(up.add_argument_group("recording in parts or snapshots (with --record; recorder/record_modes.py)"),
                RecordModes)
    up.set_defaults(func=cmd_up)

    ch = sub.add_parser("chaos", help="run the same seed with and without a fault plan (degradation table + figure), "
                                      "or soak under a random nemesis; then check the invariants")
    add_up_args(ch, "truav", "truav")
    ch.add_argument("--plan", metavar="FILE", help="fault plan TOML (examples in deploy/plans/)")
    ch.add_argument("--nemesis", choices=NEMESES,
                    help="instead of --plan: a seeded random plan (--seed) of crashes, pauses, router kills and link "
                         "faults, healed before the end, written to <out>/nemesis-plan.toml; one recorded run, no "
                         "baseline")
    ch.add_argument("--duration", type=duration_s, metavar="T",
                    help="--nemesis: how long the run lasts (e.g. 90s, 10m; sets --episodes)")
    ch.set_defaults(func=cmd_chaos, episodes=None, max_missed=CHAOS_MAX_MISSED_SHARE)
    for action in ch._actions:  # --plan's default differs from up's: enough episodes to pair
        if action.dest == "episodes":
            action.help = (f"episodes of each run (default {PLAN_EPISODES} with --plan: the effects are paired over "
                           f"them; set by --duration with --nemesis)")
        if action.dest == "max_missed":  # chaos judges missed actions itself (truav.swarm.chaos_time)
            action.help = (f"fail either run when more than this share of its actions is missing (default "
                           f"{CHAOS_MAX_MISSED_SHARE:g}: chaos judges them itself, the baseline's against a busy "
                           f"host's share, the faulted run's in its quiet tail after the heal)")

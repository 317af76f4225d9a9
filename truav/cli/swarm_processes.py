"""`truav-swarm router|world|agent|controller`: the swarm's parts, one process each (the router's own in
truav.cli.swarm_router).

Each command checks its flags and files (one line, exit 2, before anything starts), builds its
process's options and runs it: the runtime lives with the process (world.process.world_process,
agents.process.agent_host, agents.process.central_process), the stop on SIGTERM / lost supervisor / lost router
in truav.lifecycle. Building a part's parser imports its options (light modules beside each process) and no
runtime: each command imports its process's modules when it runs.
"""

from __future__ import annotations

import os

from truav.analysis.agent_loader import AGENT_KIND_PREFIX
from truav.checks import check_out_file
from truav.cli.args import add_options, non_negative_int, options_from, positive_float
from truav.cli.config import UsageError
from truav.wire import keys
from truav.cli.swarm_common import (add_command_hold_arg, add_lockstep_args, add_policy_args, add_scenario_args,
                                    add_scheme_arg, add_swarm_process_args, check_agent_scheme,
                                    config_from_args, lockstep_wait, part_creds, scenario_from, setup_logging)


def cmd_world(args) -> int:
    from truav.swarm.checks import check_creds_fit, check_plan
    from world.process.world_host import host_world
    from world.process.world_options import WorldOptions
    setup_logging(args.verbose)
    cfg = scenario_from(args)
    check_creds_fit(args, cfg)
    if args.fault_plan:
        check_plan("--fault-plan", args.fault_plan, cfg.scenario.n_uavs, args.scheme)
    if args.stats_out:
        check_out_file("--stats-out", args.stats_out)
    opts = options_from(WorldOptions, args, run=args.run, seed=args.seed, lockstep=args.lockstep,
                        lockstep_wait_s=lockstep_wait(args), fault_plan=args.fault_plan,
                        accept_replay=args.accept_replay, scheme=args.scheme)
    part_creds(args, keys.SRC_WORLD)
    return host_world(cfg, opts, config_from_args(args), args.router_timeout)


def cmd_agent(args) -> int:
    """One agent, or several (``--id`` repeated) hosted in this process: each with its own Zenoh session,
    identity, credentials, checkpoint and statistics, on its own thread (fewer processes for a large swarm)."""
    from agents.process.agent_host import ID_PLACEHOLDER, host_agents, path_of
    from agents.process.agent_options import AgentOptions, DELAY_ENV, debug_delay_s
    from truav.swarm.checks import (check_agent_start, check_beacon_cell, check_checkpoint, check_creds_fit, check_plan,
                                    check_qtable, check_scheme_flags)
    setup_logging(args.verbose)
    cfg = scenario_from(args)
    check_creds_fit(args, cfg)
    ids = args.id
    if len(set(ids)) != len(ids):
        raise UsageError(f"--id: UAV id(s) {sorted({i for i in ids if ids.count(i) > 1})} given twice")
    for uav in ids:
        if not 0 <= uav < cfg.scenario.n_uavs:
            raise UsageError(f"--id {uav} is outside [0, {cfg.scenario.n_uavs}) (scenario.n_uavs)")
    if len(ids) > 1:
        for flag, value in (("--checkpoint", args.checkpoint), ("--stats-out", args.stats_out)):
            if value and ID_PLACEHOLDER not in value:
                raise UsageError(f"{flag} {value}: with several --id, put {ID_PLACEHOLDER} in it (one file per UAV)")
    check_beacon_cell(args.beacon_cell, cfg)
    if args.lockstep and (args.beacon_every != 1 or args.beacon_cell is not None):
        raise UsageError(f"{'--beacon-every' if args.beacon_every != 1 else '--beacon-cell'}: lock-step waits for "
                         f"every live peer's beacon of each tick; beacon rate and cells are for real time only")
    wait_s = lockstep_wait(args)
    try:
        delays = {uav: debug_delay_s(os.environ.get(DELAY_ENV, ""), uav) for uav in ids}
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if args.fault_plan:
        check_plan("--fault-plan", args.fault_plan, cfg.scenario.n_uavs, args.scheme)
    check_scheme_flags(args)
    check_agent_scheme(args, cfg)
    if args.qtable and args.scheme.startswith(AGENT_KIND_PREFIX):  # read in full by the process anyway
        check_agent_start("--qtable", args.qtable, args.scheme[len(AGENT_KIND_PREFIX):], cfg, allow_mismatch=True,
                          index=args.qtable_index)
    elif args.qtable:
        check_qtable("--qtable", args.qtable, cfg, args.qtable_index, full=False)

    for uav in ids:
        if args.checkpoint:
            check_checkpoint(path_of(args.checkpoint, uav), cfg, api_agent=args.scheme.startswith(AGENT_KIND_PREFIX))
        if args.stats_out:
            check_out_file("--stats-out", path_of(args.stats_out, uav))
    configs = {}
    for uav in ids:  # each agent its own identity and, with --creds, its own certificate
        part_creds(args, keys.uav_identity(uav))
        configs[uav] = config_from_args(args)
        if args.creds:
            args.config = None

    def options_for(uav: int) -> AgentOptions:
        return options_from(AgentOptions, args, run=args.run, uav=uav, seed=args.seed, lockstep=args.lockstep,
                            lockstep_wait_s=wait_s, train=not args.greedy, checkpoint=path_of(args.checkpoint, uav),
                            stats_out=path_of(args.stats_out, uav), tick_period_s=1.0 / args.rate,
                            fault_plan=args.fault_plan, debug_delay_s=delays[uav], accept_replay=args.accept_replay,
                            scheme=args.scheme)

    return host_agents(cfg, args.run, ids, configs, options_for, args.router_timeout, args.share_beacons,
                       args.batch_beacons)


def cmd_controller(args) -> int:
    from agents.process.controller_host import host_controller
    from agents.process.controller_options import ControllerOptions
    from truav.swarm.checks import check_central_sizes, check_plan, check_policy
    setup_logging(args.verbose)
    cfg = scenario_from(args)
    if args.fault_plan:
        check_plan("--fault-plan", args.fault_plan, cfg.scenario.n_uavs, "central")
    if args.policy is not None:
        check_policy("--policy", args.policy, cfg, args.policy_index)
    check_central_sizes(cfg)
    if args.stats_out:
        check_out_file("--stats-out", args.stats_out)
    opts = options_from(ControllerOptions, args, run=args.run, seed=args.seed, lockstep=args.lockstep,
                        lockstep_wait_s=lockstep_wait(args), tick_period_s=1.0 / args.rate,
                        fault_plan=args.fault_plan, accept_replay=args.accept_replay)
    part_creds(args, keys.SRC_CONTROLLER)
    return host_controller(cfg, opts, config_from_args(args), args.router_timeout)


def add_process_commands(sub, only: str | None = None) -> None:
    """The `router`, `world`, `agent` and `controller` subcommands (in that order: `--help` lists them so); with
    ``only``, that part's alone (a part's process imports no other part's modules: each costs CPU at every start)."""
    if only is None:
        from truav.cli.swarm_router import HELP as ROUTER_HELP, add_router_args
        add_router_args(sub.add_parser("router", help=ROUTER_HELP, description=ROUTER_HELP))
    if only in (None, "world"):
        _add_world(sub)
    if only in (None, "agent"):
        _add_agent(sub)
    if only in (None, "controller"):
        _add_controller(sub)


def _add_world(sub) -> None:
    from world.process.world_options import WorldOptions
    wo = sub.add_parser("world", help="run the world process")
    add_scenario_args(wo)
    add_options(wo, WorldOptions, ["episodes"])
    add_lockstep_args(wo)
    add_options(wo, WorldOptions, ["rate_hz", "wait_agents_s", "stats_out", "max_missed_share", "snapshot_every"])
    add_scheme_arg(wo)
    add_swarm_process_args(wo, "the world")
    wo.set_defaults(func=cmd_world)


def _add_agent(sub) -> None:
    from agents.process.agent_options import AgentOptions
    ag = sub.add_parser("agent", help="run one UAV agent process")
    add_scenario_args(ag)
    ag.add_argument("--id", type=non_negative_int, required=True, action="append",
                    help="UAV id in [0, n_uavs); repeat it to host several agents in this process, each with its "
                         "own session and identity ({id} in --checkpoint and --stats-out then names each file)")
    add_options(ag, AgentOptions, ["beacon_every", "beacon_cell_m", "beacon_slots"])
    ag.add_argument("--share-beacons", action="store_true",
                    help="with several --id: one beacon subscription for all of them (each beacon crosses Zenoh "
                         "once per process, not once per agent); each agent still checks and counts its own")
    ag.add_argument("--batch-beacons", action="store_true",
                    help="lock-step: send the beacons of this process's agents of a tick as one message on "
                         "group/<first>-<last>/beacons, and hear other processes' batches")
    add_lockstep_args(ag)
    ag.add_argument("--rate", type=positive_float, default=10.0, help="the world's tick rate in Hz (paces beacons)")
    ag.add_argument("--greedy", action="store_true", help="act greedily, do not learn")
    add_options(ag, AgentOptions, ["checkpoint", "checkpoint_every", "qtable", "qtable_index", "stats_out",
                                   "snapshot_every"])
    add_scheme_arg(ag)
    add_command_hold_arg(ag)
    add_swarm_process_args(ag, "the agent")
    ag.set_defaults(func=cmd_agent)


def _add_controller(sub) -> None:
    from agents.process.controller_options import ControllerOptions
    co = sub.add_parser("controller", help="run the central scheme's controller process")
    add_scenario_args(co)
    add_lockstep_args(co)
    co.add_argument("--rate", type=positive_float, default=10.0, help="the world's tick rate in Hz (default 10)")
    add_policy_args(co)
    add_options(co, ControllerOptions, ["stats_out"])
    add_swarm_process_args(co, "the controller")
    co.set_defaults(func=cmd_controller)

"""`truav-swarm`: the decentralized TRUAV swarm as separate processes on Zenoh.

    truav-swarm up                          # short demo: own router on loopback, world, 5 agents, summary + picture
    truav-swarm up --agents 8 --episodes 5 --record runs/demo.mcap
    truav-swarm up --lockstep --qtable runs/train-15mps
    truav-swarm status                      # `up` listens on tcp/127.0.0.1:7447 when that port is free
    truav-swarm down --run demo             # finds the run's endpoint in runs/swarm-demo/swarm.json

and the parts, for other hosts or terminals (zenoh-example style flags):

    truav-swarm router -l tcp/0.0.0.0:7447
    truav-swarm world --run demo -e tcp/HOST:7447
    truav-swarm agent --id 3 --run demo -e tcp/HOST:7447
    truav-swarm controller --run demo -e tcp/HOST:7447 --policy RUN   # --scheme central's controller
"""

from __future__ import annotations

import argparse
import logging
import os
import re
import signal
import sys
import threading
from pathlib import Path

import zenoh

from truav.bus import keys
from truav.cli_config import UsageError, parse_sets
from truav.cli_args import (OneLineParser, UserError, add_transport_args, check_endpoint, check_in_file, check_out_dir, check_out_file,
                            non_negative_float, non_negative_int, positive_float, positive_int, run_main, run_name, seed_int, share,
                            tcp_port)
from truav.config import Config, load_config
from truav.bus.schema import DEFAULT_LOCKSTEP_WAIT_S
from truav.lifecycle import DEFAULT_ROUTER_TIMEOUT_S, watch_router, watch_supervisor
from truav.swarm.healing import DEFAULT_RESTART_LIMIT, DEFAULT_RESTART_POLICY, RESTART_POLICIES
from truav.nemesis import NEMESES
from truav.bus.transport import DEFAULT_ENDPOINT, Bus, apply_creds, config_from_args, run_router

log = logging.getLogger("truav.swarm")

SCHEMES = ("truav", "central", "patrol")
"""What flies the UAVs: TRUAV's agents, the central controller's commands, the patrol plan."""
DEFAULT_COMMAND_HOLD_S = 1.0
MAX_AGENTS = 50
"""Agent processes `up` and `chaos` start without --force-agents. On the 2-core reference
machine 20 agents at 10 Hz keep every deadline with a wide margin, and 50 already miss 2.4%
of their actions (each agent is its own Python process); past 50 the swarm is no longer
real time there, and hundreds of processes can load the machine before anything is printed."""


def add_scenario_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--run", type=run_name, default="demo", help="run name: keys live under truav/<run>/ (default demo)")
    p.add_argument("--seed", type=seed_int, default=0, help="seed of the run (default 0)")
    p.add_argument("--scenario", metavar="FILE", help="scenario TOML (as `truav config show` prints)")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override one scenario value (repeatable)")


def scenario_from(args) -> Config:
    return load_config(args.scenario, parse_sets(args.set))


# -- validation before anything starts -----------------------------------------------
def check_transport(args, listen_flag: str = "-l/--listen") -> None:
    """The zenoh-example flags: endpoints well formed, a -c file Zenoh can read."""
    connect = getattr(args, "connect", None) or []
    for ep in [connect] if isinstance(connect, str) else connect:  # `certs -e` takes one endpoint
        check_endpoint("-e/--connect", ep)
    for ep in getattr(args, "listen", None) or []:
        check_endpoint(listen_flag, ep)
    if not isinstance(connect, str):
        check_tls_creds(args)
    if getattr(args, "config", None) is not None:
        check_in_file("-c/--config", args.config)
        try:
            zenoh.Config.from_file(args.config)
        except zenoh.ZError as exc:
            raise UserError(f"-c/--config {args.config}: not a Zenoh config ({_one_line(exc)})") from None


def check_tls_creds(args, flag: str = "-e/--connect") -> None:
    """A tls/ endpoint is a --secure swarm's router: without this component's certificate (--creds or
    -c) Zenoh only says it cannot connect, so say what is missing, before connecting."""
    if getattr(args, "creds", None) or getattr(args, "config", None):
        return
    for ep in getattr(args, "connect", None) or []:
        if isinstance(ep, str) and ep.startswith("tls/"):
            raise UserError(f"{flag} {ep}: a TLS router (a --secure swarm) admits only clients with its "
                            f"credentials: pass --creds DIR (the run's <out>/creds)")


def _one_line(exc: Exception) -> str:
    """A Zenoh config error on one line: json5's multi-line caret diagram becomes "line L:C: what"."""
    text = str(exc).split(" at /")[0].strip()
    where = re.search(r"-->\s*(\d+:\d+)", text)
    what = re.findall(r"^\s*=\s*(.+?)\)?\s*$", text, flags=re.M)
    if where and what:
        return f"line {where.group(1)}: {what[-1]}"
    return " ".join(text.split())


def check_plan(flag: str, path: str, n_uavs: int, scheme: str | None = None):
    """A fault plan file that is valid and names only UAVs (and a controller) this swarm has."""
    from truav.faults import check_plan_for, load_plan
    check_in_file(flag, path)
    return check_plan_for(load_plan(path), n_uavs, path, scheme)


def check_qtable(flag: str, run: str, cfg: Config, index: int | None = None, full: bool = True) -> None:
    """A trained run (or its qtables.npz) whose tables fit this scenario; ``full``: read every
    entry (once, in `up`), else only the array headers (each agent process, just before it loads them)."""
    from truav import runio
    try:
        if full:
            seeds, q = runio.read_qtables(run)
            n_seeds, shape = len(seeds), q.shape
        else:
            n_seeds, shape = runio.qtable_shapes(run)
        runio.check_qtables(run, shape, cfg, exact_uavs=False)
    except runio.RunDirError as exc:
        raise UsageError(f"{flag}: {exc}") from None
    if index is not None and index >= n_seeds:
        raise UsageError(f"--qtable-index {index}: {run} holds {n_seeds} table(s) (indices 0-{n_seeds - 1})")


def check_beacon_cell(cell_m: float | None, cfg: Config) -> None:
    """--beacon-cell only where a far neighbour cannot change the state (agents/beacon_cells.py)."""
    if cell_m is not None and cfg.learner.neighbour_sectors > 0:
        raise UsageError(f"--beacon-cell {cell_m:g}: learner.neighbour_sectors = {cfg.learner.neighbour_sectors} puts "
                         f"the nearest neighbour's direction in the state, at any distance; range-limited beacons "
                         f"would change it")


def check_scheme_flags(args) -> None:
    """Flags that belong to one scheme only, given with another (one line, before anything starts)."""
    scheme = args.scheme
    if scheme != "truav":
        for flag, given in (("--qtable", args.qtable), ("--greedy", args.greedy)):
            if given:
                raise UsageError(f"{flag}: only --scheme truav flies Q-tables (this is --scheme {scheme})")
    if scheme != "central":
        if getattr(args, "policy", None) is not None:
            raise UsageError(f"--policy: only --scheme central flies a trained controller (this is --scheme {scheme})")
        if getattr(args, "command_hold", None) != DEFAULT_COMMAND_HOLD_S:
            raise UsageError(f"--command-hold: only --scheme central has commands (this is --scheme {scheme})")


def check_policy(flag: str, run: str, cfg: Config, index: int) -> None:
    """A trained central controller (`truav train --scheme central`) that fits this scenario."""
    from truav import runio
    try:
        runio.read_policy(run, index, cfg)
    except runio.RunDirError as exc:
        raise UsageError(f"{flag}: {exc}") from None


def check_central_sizes(cfg: Config) -> None:
    """The central scheme's messages are padded to the model's sizes: they must fit one bus message,
    and the controller needs torch."""
    from truav.bus import schema
    limit = schema.MAX_SMALL_PAYLOAD_BYTES
    for key in ("upload_bytes", "download_bytes"):
        value = getattr(cfg.central, key)
        if value > limit:
            raise UsageError(f"central.{key} = {value}: a message on the bus holds at most {limit} bytes")
    import importlib.util
    if importlib.util.find_spec("torch") is None:
        raise UsageError("--scheme central: the controller needs PyTorch: pip install -e '.[central]'")


def check_checkpoint(path: str, cfg: Config) -> None:
    """An agent checkpoint: resumed from if it exists (then it must be one), else creatable."""
    import json
    import zipfile
    import zlib

    import numpy as np

    from agents.state import StateEncoder
    from world.uavs import N_ACTIONS
    p = Path(path)
    if not p.exists():
        check_out_file("--checkpoint", path)
        return
    check_in_file("--checkpoint", path)
    try:
        with np.load(p, allow_pickle=False) as ck:
            shape, _, _ = ck["q"].shape, int(ck["steps"]), json.loads(str(ck["rng_state"]))
    except (OSError, EOFError, ValueError, KeyError, TypeError, AttributeError, zipfile.BadZipFile, zlib.error) as exc:
        raise UsageError(f"--checkpoint {path}: not an agent checkpoint (.npz with q, steps, rng_state): "
                         f"{type(exc).__name__}") from None
    want = (StateEncoder(cfg).n_states, N_ACTIONS)
    if shape != want:
        raise UsageError(f"--checkpoint {path}: its Q-table is {shape}, this scenario needs {want}")


EXIT_ROUTER_LOST = 1


class StopReasons:
    """Why a part stopped: the first reason is logged and kept (the logs say why a process ended)."""

    def __init__(self, stop) -> None:
        self._stop = stop
        self.first: str | None = None
        self.router_lost = False

    def because(self, reason: str) -> None:
        if self.first is None:
            self.first = reason
            log.info("stopping: %s", reason)
        self._stop()


def _stop_on_sigterm_or_orphaned(stop, bus: Bus | None = None, router_timeout_s: float | None = None) -> StopReasons:
    """``stop()`` on SIGTERM, when the `truav-swarm up` that started this process is gone, and
    (with ``bus``) when the router has been gone for ``router_timeout_s``."""
    reasons = StopReasons(stop)
    signal.signal(signal.SIGTERM, lambda *_: reasons.because("SIGTERM"))
    watch_supervisor(lambda: reasons.because("the truav-swarm up that started this process is gone"))
    if bus is not None and router_timeout_s is not None:
        def router_lost(seconds: float) -> None:
            reasons.router_lost = True
            log.error("no router for %.1f s (it stopped, or the network to it is down)", seconds)
            reasons.because(f"router lost for {seconds:.1f} s")
        watch_router(bus.session, router_timeout_s, router_lost)
    return reasons


GIL_SWITCH_INTERVAL_S = 0.0005
"""Bus callbacks run on Zenoh's threads and need the GIL: with Python's default
5 ms switch interval a message can wait that long behind the main thread."""


def _setup_logging(verbose: bool) -> None:
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    # INFO by default: a part's log says what it did (joins, losses, checkpoints, why it stopped);
    # -v adds TRUAV's own debug lines (not the libraries').
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    if verbose:
        logging.getLogger("truav").setLevel(logging.DEBUG)


# -- the parts ---------------------------------------------------------------------
def cmd_router(args) -> int:
    _setup_logging(args.verbose)
    stop = threading.Event()
    _stop_on_sigterm_or_orphaned(stop.set)
    _creds(args, "router")
    listen = args.listen or ([] if args.config else [DEFAULT_ENDPOINT])  # a config file keeps its own
    try:
        # "router listening" is printed once the endpoints are open: `truav-swarm up` waits for that line.
        run_router(listen, connect=args.connect, config_file=args.config, stop=stop,
                   on_ready=lambda: print(f"router listening on {', '.join(listen) or 'the endpoints of ' + args.config}",
                                          flush=True))
    except KeyboardInterrupt:
        pass
    except zenoh.ZError as exc:
        print(f"truav-swarm router: error: cannot listen on {', '.join(listen)}: {_zenoh_reason(exc)}",
              file=sys.stderr, flush=True)
        return 1
    log.info("router stopped")
    return 0


def _zenoh_reason(exc: Exception) -> str:
    """The useful part of a Zenoh error ("Address already in use (os error 98)"), without source paths."""
    text = str(exc).split(" at /")[0].strip()
    return text.rsplit(": ", 1)[-1] if ": " in text else text


def cmd_world(args) -> int:
    from world.world_process import WorldNode, WorldOptions, write_stats
    _setup_logging(args.verbose)
    cfg = scenario_from(args)
    _check_creds_fit(args, cfg)
    if args.fault_plan:
        check_plan("--fault-plan", args.fault_plan, cfg.scenario.n_uavs, args.scheme)
    if args.stats_out:
        check_out_file("--stats-out", args.stats_out)
    opts = WorldOptions(run=args.run, seed=args.seed, episodes=args.episodes, lockstep=args.lockstep,
                        lockstep_wait_s=lockstep_wait(args), rate_hz=args.rate, wait_agents_s=args.wait_agents,
                        stats_out=args.stats_out,
                        fault_plan=args.fault_plan, accept_replay=args.accept_replay, scheme=args.scheme)
    _creds(args, keys.SRC_WORLD)
    with Bus(keys.SRC_WORLD, args.run, config_from_args(args)) as bus:
        node = WorldNode(cfg, opts, bus)
        reasons = _stop_on_sigterm_or_orphaned(node.stop, bus, args.router_timeout)
        try:
            stats = node.run()
        except KeyboardInterrupt:
            reasons.because("interrupted")
            stats = node.stats
        stats.rejected = bus.rejections.as_dict()
    if args.stats_out:
        write_stats(args.stats_out, stats)
    log.info("world stopped after %d episode(s), %d tick(s) (%s)%s", len(stats.episodes), stats.ticks,
             reasons.first or ("finished its episodes" if len(stats.episodes) == opts.episodes
                               else "a shutdown request, see above"),
             f"; statistics in {args.stats_out}" if args.stats_out else "")
    return EXIT_ROUTER_LOST if reasons.router_lost else 0


class SharedBeacons:
    """One beacon subscription for every agent a process hosts (``--share-beacons``).

    Each beacon then crosses Zenoh once per process instead of once per agent; every agent still
    gets it in its own inbox, through its own bus's link filter, schema and guard checks, and
    counted on its own bus.  The subscription lives on the first agent's session (its grants
    allow every beacon, as every agent's do); the hosted agents stop together."""

    def __init__(self, run: str) -> None:
        self.key = keys.all_beacons(run)
        self.boxes: list = []
        self._lock = threading.Lock()

    def __call__(self, bus: Bus, **inbox_opts):
        from truav.bus.inbox import Inbox
        box = Inbox(bus, **inbox_opts)
        with self._lock:
            first = not self.boxes
            self.boxes = [*self.boxes, box]  # copied: arrivals iterate without the lock
        if first:
            bus.feed(self, self.key)
        return box

    def on_sample(self, sample) -> None:  # zenoh's callback thread: an append per hosted agent
        for box in self.boxes:
            box.on_sample(sample)


ID_PLACEHOLDER = "{id}"
"""In --checkpoint and --stats-out of a process hosting several agents: replaced by each UAV's id."""


def cmd_agent(args) -> int:
    """One agent, or several (``--id`` repeated) hosted in this process: each with its own Zenoh session,
    identity, credentials, checkpoint and statistics, on its own thread (fewer processes for a large swarm)."""
    from agents.agent_process import DELAY_ENV, AgentOptions, debug_delay_s
    from agents.scheme_process import make_agent_node
    _setup_logging(args.verbose)
    cfg = scenario_from(args)
    _check_creds_fit(args, cfg)
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
    if args.qtable:
        check_qtable("--qtable", args.qtable, cfg, args.qtable_index, full=False)

    def path_of(template: str | None, uav: int) -> str | None:
        return template.replace(ID_PLACEHOLDER, str(uav)) if template else None

    for uav in ids:
        if args.checkpoint:
            check_checkpoint(path_of(args.checkpoint, uav), cfg)
        if args.stats_out:
            check_out_file("--stats-out", path_of(args.stats_out, uav))
    configs = {}
    for uav in ids:  # each agent its own identity and, with --creds, its own certificate
        _creds(args, keys.uav_identity(uav))
        configs[uav] = config_from_args(args)
        if args.creds:
            args.config = None
    results: dict[int, tuple[object, StopReasons]] = {}
    stops: list = []
    failed: list[BaseException] = []
    started = threading.Barrier(len(ids) + 1) if len(ids) > 1 else None
    shared = SharedBeacons(args.run) if args.share_beacons and len(ids) > 1 else None

    def host(uav: int) -> None:
        opts = AgentOptions(run=args.run, uav=uav, seed=args.seed, lockstep=args.lockstep, lockstep_wait_s=wait_s,
                            train=not args.greedy,
                            checkpoint=path_of(args.checkpoint, uav), checkpoint_every=args.checkpoint_every,
                            qtable=args.qtable, qtable_index=args.qtable_index, stats_out=path_of(args.stats_out, uav),
                            tick_period_s=1.0 / args.rate, fault_plan=args.fault_plan, debug_delay_s=delays[uav],
                            accept_replay=args.accept_replay, scheme=args.scheme, command_hold_s=args.command_hold,
                            beacon_every=args.beacon_every, beacon_cell_m=args.beacon_cell)
        with Bus(keys.uav_identity(uav), args.run, configs[uav]) as bus:
            node = make_agent_node(cfg, opts, bus, beacon_inbox=shared)
            reasons = StopReasons(node.stop)
            if args.router_timeout is not None:
                def router_lost(seconds: float, reasons=reasons) -> None:
                    reasons.router_lost = True
                    log.error("uav %d: no router for %.1f s (it stopped, or the network to it is down)", uav, seconds)
                    reasons.because(f"router lost for {seconds:.1f} s")
                watch_router(bus.session, args.router_timeout, router_lost)
            results[uav] = (node, reasons)
            stops.append(reasons.because)
            if stopping:  # SIGTERM (or a lost supervisor) while this agent was starting
                reasons.because(stopping[0])
            if started is not None:
                started.wait()
            log.info("uav %d joined run %s (%s)", uav, args.run, args.scheme if args.scheme != "truav"
                     else "greedy" if args.greedy else "learning")
            try:
                node.run()
            except KeyboardInterrupt:
                reasons.because("interrupted")
                node.checkpoint()
            node.write_stats()
        log.info("uav %d stopped after %d step(s) (%s); final checkpoint %s, statistics %s", uav, node.steps,
                 reasons.first or "shutdown", opts.checkpoint or "(none: no --checkpoint)", opts.stats_out or "(none)")

    stopping: list[str] = []

    def stop_all(reason: str) -> None:
        stopping.append(reason)
        for because in list(stops):
            because(reason)

    signal.signal(signal.SIGTERM, lambda *_: stop_all("SIGTERM"))
    watch_supervisor(lambda: stop_all("the truav-swarm up that started this process is gone"))
    if started is None:  # one agent: on the main thread, as always
        host(ids[0])
    else:
        def hosted(uav: int) -> None:
            try:
                host(uav)
            except BaseException as exc:  # noqa: BLE001 - reported below, the others stop
                failed.append(exc)
                log.exception("uav %d failed", uav)
                if started.n_waiting:
                    started.abort()
                stop_all(f"uav {uav} failed")
        threads = [threading.Thread(target=hosted, args=(uav,), name=f"uav{uav}") for uav in ids]
        for t in threads:
            t.start()
        try:
            started.wait()
        except threading.BrokenBarrierError:
            pass
        try:
            while any(t.is_alive() for t in threads):
                for t in threads:
                    t.join(0.2)
        except KeyboardInterrupt:
            stop_all("interrupted")
            for t in threads:
                t.join()
        if failed:
            raise failed[0]
    return EXIT_ROUTER_LOST if any(r.router_lost for _, r in results.values()) else 0


def cmd_controller(args) -> int:
    from agents.central_process import ControllerNode, ControllerOptions
    _setup_logging(args.verbose)
    cfg = scenario_from(args)
    if args.fault_plan:
        check_plan("--fault-plan", args.fault_plan, cfg.scenario.n_uavs, "central")
    if args.policy is not None:
        check_policy("--policy", args.policy, cfg, args.policy_index)
    check_central_sizes(cfg)
    if args.stats_out:
        check_out_file("--stats-out", args.stats_out)
    opts = ControllerOptions(run=args.run, seed=args.seed, lockstep=args.lockstep, lockstep_wait_s=lockstep_wait(args),
                             policy=args.policy,
                             policy_index=args.policy_index, tick_period_s=1.0 / args.rate,
                             stats_out=args.stats_out, fault_plan=args.fault_plan, accept_replay=args.accept_replay)
    _creds(args, keys.SRC_CONTROLLER)
    with Bus(keys.SRC_CONTROLLER, args.run, config_from_args(args)) as bus:
        node = ControllerNode(cfg, opts, bus)
        reasons = _stop_on_sigterm_or_orphaned(node.stop, bus, args.router_timeout)
        log.info("controller joined run %s (%s)", args.run, f"policy {args.policy}" if args.policy else "learning online")
        try:
            node.run()
        except KeyboardInterrupt:
            reasons.because("interrupted")
        node.write_stats()
    log.info("controller stopped after %d tick(s), %d command(s) (%s)", node.stats["ticks"], node.stats["commands"],
             reasons.first or "shutdown")
    return EXIT_ROUTER_LOST if reasons.router_lost else 0


def _pid_running(pid) -> bool:
    """Whether process ``pid`` exists (one of another user's counts; a zombie does not)."""
    if not isinstance(pid, int) or isinstance(pid, bool) or pid <= 0:
        return True  # unknown: do not call the run ended on a guess
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        except OSError:
            return True
        return True


def _endpoint_from_out(args, out: Path | None, explicit: bool, need_run: bool = False) -> None:
    """Without -e, connect where the run writing ``out`` has its router (from its swarm.json). An --out
    the user named (or, with ``need_run``, the default one) must hold one: connecting to the default
    endpoint instead would be a silent guess. A run that has ended (its summary written, or its
    supervisor gone) is said to have ended, not looked for on a router that is no longer there."""
    from truav.swarm.outdir import RUN_FILE, SUMMARY_FILE, read_run_file
    if args.connect or args.config or getattr(args, "creds", None) or out is None:  # --creds has its router
        return
    info = read_run_file(out)
    if info and isinstance(info, dict) and isinstance(info.get("endpoint"), str) and info["endpoint"]:
        check_endpoint(f"{out / RUN_FILE}: endpoint", info["endpoint"])
        run = info.get("run") if isinstance(info.get("run"), str) else args.run
        if (out / SUMMARY_FILE).is_file():  # written when a run ends; removed when one starts
            raise UserError(f"run {run!r} in {out} has ended ({out / SUMMARY_FILE} holds its summary): "
                            f"nothing of it is running")
        if not _pid_running(info.get("supervisor_pid")):
            raise UserError(f"run {run!r} in {out} has ended (its supervisor, PID {info['supervisor_pid']} "
                            f"in {out / RUN_FILE}, is not running)")
        args.connect = [info["endpoint"]]
    elif explicit:
        raise UserError(f"--out {out}: no swarm run's {RUN_FILE} with its router endpoint there "
                        f"(a directory `truav-swarm up --out` wrote); or give -e/--connect ENDPOINT")
    elif need_run:
        raise UserError(f"--run {args.run}: no such run: {out / RUN_FILE} does not exist (`truav-swarm up "
                        f"--run {args.run}` writes it); for a run with another --out pass --out DIR, or "
                        f"-e/--connect ENDPOINT")
    check_tls_creds(args, f"{out / RUN_FILE}: endpoint")


def cmd_status(args) -> int:
    if args.out is not None:
        check_out_dir("--out", args.out)
    _endpoint_from_out(args, Path(args.out) if args.out else None, explicit=args.out is not None)
    from truav.swarm.secure_cli import rejections_heard
    _creds(args, "supervisor")
    conf = config_from_args(args)
    pattern = keys.all_alive(args.run) if args.run else "truav/*/alive/**"
    with Bus("status", args.run or "status", conf) as bus:
        heard = rejections_heard(bus, args.run)
        tokens = sorted(bus.alive(pattern, timeout=args.timeout))
        # Agents report once a second (agents.agent_process.HEALTH_PERIOD_S): wait a little longer for theirs.
        rejected = heard(min(args.timeout, 0.5) + 1.2 if tokens else 0.0, tokens)
    if not tokens:
        print("no TRUAV process alive" + (f" in run {args.run}" if args.run else ""))
        return 1
    for token in tokens:
        print(token)
    for line in rejected:
        print(line)
    return 0


DOWN_LISTENER_WAIT_S = 5.0
"""How long `down` waits for the run's processes to be known as listeners before it sends."""


def cmd_down(args) -> int:
    from truav.swarm.supervisor import DOWN_IDENTITY, stop_recorded_pids
    from truav.bus import schema
    if args.out is not None:
        check_out_dir("--out", args.out)
    out = Path(args.out) if args.out else Path("runs") / f"swarm-{args.run}"
    _endpoint_from_out(args, out, explicit=args.out is not None, need_run=True)
    _creds(args, "supervisor")
    with Bus(DOWN_IDENTITY, args.run, config_from_args(args)) as bus:
        key = keys.control(args.run, "shutdown")
        if not bus.await_subscribers(key, DOWN_LISTENER_WAIT_S):
            log.warning("no process of run %s listens for its shutdown (yet); sending it anyway", args.run)
        bus.publish(key, schema.Control(command="shutdown", args={}))
    # The swarm stops itself on the shutdown (its supervisor stops the router and recorder last);
    # only what still runs after a while is signalled, from the pid file.
    stopped = stop_recorded_pids(out, wait_s=args.wait)
    print(f"shutdown sent to run {args.run}" + (f"; {stopped} process(es) still running after {args.wait:g} s "
                                                 f"were sent SIGTERM (from {out}/pids.json)" if stopped else ""))
    return 0


def _check_creds_fit(args, cfg: Config) -> None:
    """``--creds`` made for another number of agents than the scenario flies: one line, before anything starts."""
    if not getattr(args, "creds", None):
        return
    from truav.bus import security
    try:
        creds = security.load(args.creds, args.run)
    except security.CredentialsError as exc:
        raise UsageError(str(exc)) from None
    if creds.n_uavs != cfg.scenario.n_uavs:
        raise UsageError(f"--creds {args.creds} was made for {creds.n_uavs} agents, the scenario has "
                         f"{cfg.scenario.n_uavs} (scenario.n_uavs): pass --set scenario.n_uavs={creds.n_uavs}")


def _creds(args, identity: str) -> None:
    """``--creds DIR``: this part's zenoh config from DIR (one line naming the flag if DIR is wrong)."""
    try:
        apply_creds(args, identity)
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def _swarm_options(args):
    """The scenario and options of `up`/`chaos`, every flag and file checked: nothing has started yet."""
    from truav.swarm.supervisor import SwarmOptions
    sets = parse_sets(args.set).get("scenario", {})
    for flag, key, value in (("--agents", "n_uavs", args.agents), ("--steps", "steps_per_episode", args.steps)):
        if value is not None and key in sets and sets[key] != value:
            raise UsageError(f"{flag} {value} contradicts --set scenario.{key}={sets[key]}; give one of them")
    cfg = scenario_from(args)
    if args.agents is not None:
        cfg = cfg.replace(scenario={"n_uavs": args.agents})
    if args.steps is not None:
        cfg = cfg.replace(scenario={"steps_per_episode": args.steps})
    n = cfg.scenario.n_uavs
    if n > MAX_AGENTS and not args.force_agents:
        raise UsageError(f"--agents {n}" + ("" if args.agents is not None else " (from scenario.n_uavs)")
                         + f": more than {MAX_AGENTS} agent processes is past what the reference machine runs in "
                         f"real time (see MAX_AGENTS in truav/swarm/cli.py); add --force-agents to start them anyway")
    if len(args.listen) > 1:
        raise UsageError(f"-l/--listen: the swarm's router listens on one endpoint, got {len(args.listen)}")
    for ep in args.listen:
        check_endpoint("-l/--listen", ep, tcp_only=True)  # the supervisor waits for the router's TCP port
    if args.out is not None:
        check_out_dir("--out", args.out)
    if args.record is not None:
        check_out_file("--record", args.record)
    check_scheme_flags(args)
    if args.qtable is not None:
        check_qtable("--qtable", args.qtable, cfg)
    if args.policy is not None:
        check_policy("--policy", args.policy, cfg, args.policy_index)
    if args.scheme == "central":
        check_central_sizes(cfg)
    if args.fault_plan is not None:
        check_plan("--fault-plan", args.fault_plan, n, args.scheme)
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
    if args.agents_per_process > 1 and args.fault_plan is not None:
        kinds = {f.kind for f in load_plan_for(args.fault_plan).faults} & {"crash", "freeze"}
        if kinds:
            raise UsageError(f"--agents-per-process {args.agents_per_process}: the fault plan {args.fault_plan} "
                             f"{' and '.join(sorted(kinds))}es single agent processes; use 1 agent per process")
    opts = SwarmOptions(run=args.run, seed=args.seed, episodes=args.episodes, lockstep=args.lockstep,
                        lockstep_wait_s=lockstep_wait(args), rate_hz=args.rate, record=args.record, qtable=args.qtable,
                        greedy=args.greedy,
                        out=args.out, listen=args.listen[0] if args.listen else None,
                        plot=not args.no_plot, quiet=args.quiet, wait_agents_s=args.wait_agents,
                        fault_plan=args.fault_plan, foxglove_port=getattr(args, "foxglove", None),
                        geo_origin=args.geo_origin, verbose=args.verbose, resume=args.resume, force=args.force,
                        max_missed_share=args.max_missed, router_timeout_s=args.router_timeout,
                        secure=args.secure, scheme=args.scheme, policy=args.policy, policy_index=args.policy_index,
                        command_hold_s=args.command_hold, beacon_every=beacon_every, beacon_cell_m=args.beacon_cell,
                        agents_per_process=args.agents_per_process, share_beacons=args.share_beacons,
                        restart=args.restart, restart_limit=args.restart_limit)
    return cfg, opts


def load_plan_for(path: str):
    from truav.faults import load_plan
    return load_plan(path)


def duration_s(text: str) -> float:
    """A run's length: seconds, or a number with s, m or h (90, 90s, 10m, 1h)."""
    m = re.fullmatch(r"\s*(\d+(?:\.\d*)?)\s*([smh]?)\s*", text)
    if not m or float(m.group(1)) <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive duration such as 90s, 10m or 1h, got {text!r}")
    return float(m.group(1)) * {"": 1, "s": 1, "m": 60, "h": 3600}[m.group(2)]


def cmd_chaos(args) -> int:
    from truav.swarm.chaos import run_chaos, run_nemesis
    if args.fault_plan is not None:  # one plan per chaos run: the faulted half flies --plan
        raise UsageError("--fault-plan: chaos takes its plan from --plan (the baseline run has none); "
                         "drop --fault-plan")
    if (args.plan is None) == (args.nemesis is None):
        raise UsageError("--plan FILE or --nemesis random: give one of them")
    if args.nemesis is None:
        for flag, value in (("--duration", args.duration),):
            if value is not None:
                raise UsageError(f"{flag}: only with --nemesis (a --plan run lasts --episodes)")
        args.episodes = 2 if args.episodes is None else args.episodes
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
    cfg, opts = _swarm_options(args)
    if args.nemesis is not None:
        import math
        opts.episodes = max(1, math.ceil(args.duration * opts.rate_hz / cfg.scenario.steps_per_episode))
        return run_nemesis(cfg, opts, args.nemesis, args.duration)
    check_plan("--plan", args.plan, cfg.scenario.n_uavs, args.scheme)
    return run_chaos(cfg, opts, args.plan)


def cmd_faults(args) -> int:
    from truav.bus import schema
    from truav.fault_filter import CONTROL_FAULTS
    from truav.faults import load_plan
    check_in_file("--plan", args.plan)
    plan = load_plan(args.plan)
    _creds(args, "supervisor")
    with Bus("supervisor", args.run, config_from_args(args)) as bus:
        key = keys.control(args.run, CONTROL_FAULTS)
        if not bus.await_subscribers(key, DOWN_LISTENER_WAIT_S):
            log.warning("no process of run %s listens for fault plans (yet); sending it anyway", args.run)
        bus.publish(key, schema.Control(command=CONTROL_FAULTS, args=plan.to_dict()))
    print(f"sent a plan of {len(plan.link_faults)} link fault(s) to run {args.run} "
          f"(crashes and freezes are scheduled by `truav-swarm up --fault-plan`)")
    return 0


def cmd_view(args) -> int:
    from recorder.foxglove import FoxgloveMirror, Geometry
    from truav.swarm.view import serve
    _setup_logging(args.verbose)
    cfg = scenario_from(args)
    stop = threading.Event()
    _stop_on_sigterm_or_orphaned(stop.set)
    mirror = FoxgloveMirror(Geometry.from_config(cfg), args.geo_origin)

    def ready(port: int) -> None:
        print(f"Foxglove: open ws://127.0.0.1:{port} (run {args.run}); layout: deploy/foxglove-layout.json",
              flush=True)

    _creds(args, "view")
    try:
        serve(args.run, config_from_args(args), mirror, port=args.port, stop=stop, ready=ready)
    except KeyboardInterrupt:
        pass
    except RuntimeError as exc:  # the SDK's server could not bind (port in use)
        raise UsageError(f"--port {args.port}: the Foxglove server could not start ({exc})") from None
    return 0


def _origin(text: str):
    from recorder.foxglove import parse_origin
    try:
        return parse_origin(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_geo_origin_arg(p: argparse.ArgumentParser) -> None:
    from recorder.foxglove import DEFAULT_ORIGIN
    p.add_argument("--geo-origin", type=_origin, default=DEFAULT_ORIGIN, metavar="LAT,LON",
                   help="where the area's centre sits on Foxglove's map, degrees (default %.4f,%.4f, Paris)"
                   % DEFAULT_ORIGIN)


def cmd_up(args) -> int:
    from truav.swarm.supervisor import run_swarm
    cfg, opts = _swarm_options(args)
    return run_swarm(cfg, opts)


# -- parser ------------------------------------------------------------------------
def add_scheme_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scheme", choices=SCHEMES, default="truav",
                   help="what flies the UAVs: truav (independent Q-learning agents, default), central (a controller "
                        "process commands every UAV each tick), patrol (the pre-planned patrol)")


def add_command_hold_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--command-hold", type=non_negative_float, default=DEFAULT_COMMAND_HOLD_S, metavar="S",
                   help="--scheme central: without a fresh command a UAV keeps its last one this many seconds "
                        f"(world clock), then hovers (default {DEFAULT_COMMAND_HOLD_S:g})")


def add_policy_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--policy", metavar="RUN", help="--scheme central: fly this trained controller (`truav train "
                                                   "--scheme central` output); default: learn online")
    p.add_argument("--policy-index", type=non_negative_int, default=0, help="which seed's policy of that run (default 0)")


def add_lockstep_args(p: argparse.ArgumentParser, help_lockstep: str | None = None) -> None:
    p.add_argument("--lockstep", action="store_true", help=help_lockstep)
    p.add_argument("--lockstep-wait", type=positive_float, metavar="S",
                   help="lock-step: wait this long for a live agent's action or beacon (a paused process) before "
                        "going on without it; the run is then not exact and fails (default "
                        f"{DEFAULT_LOCKSTEP_WAIT_S:g})")


def lockstep_wait(args) -> float:
    """--lockstep-wait, or its default; given without --lockstep it is a mistake (one line, exit 2)."""
    if args.lockstep_wait is not None and not args.lockstep:
        raise UsageError(f"--lockstep-wait {args.lockstep_wait:g}: only lock-step waits; add --lockstep or drop it")
    return DEFAULT_LOCKSTEP_WAIT_S if args.lockstep_wait is None else args.lockstep_wait


def add_up_args(up: argparse.ArgumentParser) -> None:
    add_scenario_args(up)
    add_scheme_arg(up)
    add_policy_args(up)
    add_command_hold_arg(up)
    up.add_argument("--agents", type=positive_int,
                    help=f"number of UAV agents (default scenario.n_uavs, 5; at most {MAX_AGENTS} without --force-agents)")
    up.add_argument("--force-agents", action="store_true",
                    help=f"start more than {MAX_AGENTS} agent processes (not real time on a 2-core machine)")
    up.add_argument("--episodes", type=positive_int, default=2, help="episodes before the swarm stops (default 2)")
    up.add_argument("--steps", type=positive_int, help="steps per episode (default scenario.steps_per_episode, 100)")
    add_lockstep_args(up, "the world waits for every live agent each tick")
    up.add_argument("--rate", type=positive_float, default=10.0, help="real-time tick rate in Hz (default 10)")
    up.add_argument("--record", metavar="FILE", help="record every message to this MCAP file")
    up.add_argument("--qtable", metavar="RUN", help="start agents from a trained run (truav train output)")
    up.add_argument("--greedy", action="store_true", help="agents act greedily and do not learn")
    up.add_argument("--out", help="directory for stats, checkpoints and the picture (default runs/swarm-<run>)")
    up.add_argument("-l", "--listen", action="append", default=[], metavar="ENDPOINT",
                    help=f"router endpoint (default {DEFAULT_ENDPOINT} if that port is free, else a free loopback port)")
    up.add_argument("--resume", action="store_true",
                    help="continue the run in --out (agents resume from its checkpoints; same scenario only)")
    up.add_argument("--force", action="store_true",
                    help="delete an earlier run's files in --out (and overwrite --record) instead of refusing")
    up.add_argument("--max-missed", type=share, default=0.5, metavar="SHARE",
                    help="fail the run when more than this share of actions is missing (default 0.5)")
    up.add_argument("--router-timeout", type=positive_float, default=DEFAULT_ROUTER_TIMEOUT_S, metavar="S",
                    help=f"world and agents stop this long after losing their router (default {DEFAULT_ROUTER_TIMEOUT_S:g})")
    up.add_argument("-v", "--verbose", action="store_true",
                    help="debug lines in every process's log, and each process's start (PID, log file) on the console")
    up.add_argument("--wait-agents", type=positive_float, default=60.0,
                    help="seconds the world waits for all agents to join before the first tick (default 60)")
    up.add_argument("--fault-plan", metavar="FILE", help="inject the faults of this plan (see deploy/plans/)")
    up.add_argument("--secure", action="store_true",
                    help="lock the bus: a fresh CA and one certificate per component in <out>/creds, mutual TLS, "
                         "and the router's access control (see `truav-swarm acl explain`)")
    up.add_argument("--beacon-hz", type=positive_float, metavar="HZ",
                    help="real time: beacons at this rate instead of every tick (1: the Remote ID rate; must divide "
                         "--rate), offset by id")
    up.add_argument("--beacon-cell", type=positive_float, metavar="M",
                    help="real time: range-limited beacons under map cells of M metres; each agent hears only the "
                         "cells within range of it, and decides as with all beacons (agents/beacon_cells.py)")
    up.add_argument("--agents-per-process", type=positive_int, default=1, metavar="K",
                    help="host K agents per OS process, each with its own session, identity and files (default 1)")
    up.add_argument("--share-beacons", action="store_true",
                    help="with --agents-per-process K > 1: each agent process subscribes to beacons once for its K "
                         "agents (each still checks, filters and counts its own)")
    up.add_argument("--restart", choices=RESTART_POLICIES, default=DEFAULT_RESTART_POLICY,
                    help="on-failure (default): restart an agent or the controller that dies on its own, from its "
                         "checkpoint, after a backoff, and a dead router on its endpoint; never: leave them down "
                         "(truav/swarm/healing.py; in lock-step a restart makes the run inexact, and the summary says so)")
    up.add_argument("--restart-limit", type=non_negative_int, default=DEFAULT_RESTART_LIMIT, metavar="N",
                    help=f"restarts of one process before it is left down and the run fails (default "
                         f"{DEFAULT_RESTART_LIMIT})")
    up.add_argument("--no-plot", action="store_true", help="skip the summary picture")
    up.add_argument("--quiet", action="store_true", help="no live status table")
    up.add_argument("--foxglove", type=tcp_port, nargs="?", const=8765, metavar="PORT",
                    help="serve the run live to the Foxglove app on ws://127.0.0.1:PORT (default 8765)")
    add_geo_origin_arg(up)


def add_swarm_process_args(p: argparse.ArgumentParser, who: str) -> None:
    """Flags the world and an agent process share: faults, router loss, replay, logging, transport."""
    p.add_argument("--fault-plan", metavar="FILE", help=f"apply this plan's link faults to what {who} receives")
    p.add_argument("--router-timeout", type=positive_float, default=DEFAULT_ROUTER_TIMEOUT_S, metavar="S",
                   help=f"stop this long after losing the router (default {DEFAULT_ROUTER_TIMEOUT_S:g})")
    p.add_argument("--accept-replay", action="store_true",
                   help="act on traffic a replay puts into this run (dropped and counted by default)")
    p.add_argument("-v", "--verbose", action="store_true", help="debug lines in the log")
    add_transport_args(p)


def build_parser() -> argparse.ArgumentParser:
    ap = OneLineParser(prog="truav-swarm", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True, metavar="COMMAND")

    up = sub.add_parser("up", help="start router, world, agents (and recorder); live status; summary at the end")
    add_up_args(up)
    up.set_defaults(func=cmd_up)

    ch = sub.add_parser("chaos", help="run the same seed with and without a fault plan (degradation table + figure), "
                                      "or soak under a random nemesis; then check the invariants")
    add_up_args(ch)
    ch.add_argument("--plan", metavar="FILE", help="fault plan TOML (examples in deploy/plans/)")
    ch.add_argument("--nemesis", choices=NEMESES,
                    help="instead of --plan: a seeded random plan (--seed) of crashes, pauses, router kills and link "
                         "faults, healed before the end, written to <out>/nemesis-plan.toml; one recorded run, no "
                         "baseline")
    ch.add_argument("--duration", type=duration_s, metavar="T",
                    help="--nemesis: how long the run lasts (e.g. 90s, 10m; sets --episodes)")
    ch.set_defaults(func=cmd_chaos, episodes=None)

    fa = sub.add_parser("faults", help="replace the fault plan of a running swarm (link faults)")
    fa.add_argument("--run", type=run_name, default="demo")
    fa.add_argument("--plan", required=True, metavar="FILE", help="fault plan TOML; an empty file clears all faults")
    add_transport_args(fa)
    fa.set_defaults(func=cmd_faults)

    st = sub.add_parser("status", help="who is alive (from liveliness tokens)")
    st.add_argument("--run", type=run_name, help="only this run")
    st.add_argument("--timeout", type=positive_float, default=1.0)
    st.add_argument("--out", help="connect to the router of the run writing this directory (its swarm.json)")
    add_transport_args(st)
    st.set_defaults(func=cmd_status)

    dn = sub.add_parser("down", help="ask a running swarm to shut down")
    dn.add_argument("--run", type=run_name, default="demo")
    dn.add_argument("--out", help="the swarm's output directory with swarm.json and pids.json "
                                  "(default runs/swarm-<run>; gives the endpoint when -e is not given)")
    dn.add_argument("--wait", type=positive_float, default=30.0, metavar="S",
                    help="seconds to let the swarm stop itself before signalling what still runs (default 30)")
    add_transport_args(dn)
    dn.set_defaults(func=cmd_down)

    vw = sub.add_parser("view", help="serve a live run or a replay to the Foxglove app (WebSocket, loopback)")
    add_scenario_args(vw)
    vw.add_argument("--port", type=tcp_port, default=8765, help="WebSocket port on 127.0.0.1 (default 8765; 0: any)")
    add_geo_origin_arg(vw)
    vw.add_argument("-v", "--verbose", action="store_true")
    add_transport_args(vw)
    vw.set_defaults(func=cmd_view)

    ro = sub.add_parser("router", help="run a Zenoh router")
    add_transport_args(ro)
    ro.add_argument("-v", "--verbose", action="store_true")
    ro.set_defaults(func=cmd_router)

    wo = sub.add_parser("world", help="run the world process")
    add_scenario_args(wo)
    wo.add_argument("--episodes", type=positive_int, default=2)
    add_lockstep_args(wo)
    wo.add_argument("--rate", type=positive_float, default=10.0)
    wo.add_argument("--wait-agents", type=positive_float, default=30.0, help="seconds to wait for all agents (default 30)")
    wo.add_argument("--stats-out", metavar="FILE", help="write per-episode metrics and timing as JSON")
    add_scheme_arg(wo)
    add_swarm_process_args(wo, "the world")
    wo.set_defaults(func=cmd_world)

    ag = sub.add_parser("agent", help="run one UAV agent process")
    add_scenario_args(ag)
    ag.add_argument("--id", type=non_negative_int, required=True, action="append",
                    help="UAV id in [0, n_uavs); repeat it to host several agents in this process, each with its "
                         "own session and identity ({id} in --checkpoint and --stats-out then names each file)")
    ag.add_argument("--beacon-every", type=positive_int, default=1, metavar="TICKS",
                    help="real time: send a beacon every TICKS ticks, offset by id (10 at 10 Hz: 1 Hz, the Remote ID "
                         "rate; default 1)")
    ag.add_argument("--beacon-cell", type=positive_float, metavar="M",
                    help="real time: range-limited beacons under map cells of M metres; hear only cells within range "
                         "(agents/beacon_cells.py; default: all-to-all)")
    ag.add_argument("--share-beacons", action="store_true",
                    help="with several --id: one beacon subscription for all of them (each beacon crosses Zenoh "
                         "once per process, not once per agent); each agent still checks and counts its own")
    add_lockstep_args(ag)
    ag.add_argument("--rate", type=positive_float, default=10.0, help="the world's tick rate in Hz (paces beacons)")
    ag.add_argument("--greedy", action="store_true", help="act greedily, do not learn")
    ag.add_argument("--checkpoint", metavar="FILE", help="Q-table checkpoint (.npz): resume from it, rewrite it")
    ag.add_argument("--checkpoint-every", type=positive_int, default=100, help="steps between checkpoints (default 100)")
    ag.add_argument("--qtable", metavar="RUN", help="start from a trained run's Q-table")
    ag.add_argument("--qtable-index", type=non_negative_int, default=0,
                    help="which seed's table of that run (default 0)")
    ag.add_argument("--stats-out", metavar="FILE", help="write beacon latency statistics as JSON at exit")
    add_scheme_arg(ag)
    add_command_hold_arg(ag)
    add_swarm_process_args(ag, "the agent")
    ag.set_defaults(func=cmd_agent)

    co = sub.add_parser("controller", help="run the central scheme's controller process")
    add_scenario_args(co)
    add_lockstep_args(co)
    co.add_argument("--rate", type=positive_float, default=10.0, help="the world's tick rate in Hz (default 10)")
    add_policy_args(co)
    co.add_argument("--stats-out", metavar="FILE", help="write the controller's statistics as JSON at exit")
    add_swarm_process_args(co, "the controller")
    co.set_defaults(func=cmd_controller)

    from truav.swarm.secure_cli import add_security_commands
    add_security_commands(sub)

    try:
        from recorder.cli import add_swarm_commands
    except ImportError:  # recorder commands not installed
        pass
    else:
        add_swarm_commands(sub)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)

    def run() -> int:
        if args.command != "up" and args.command != "chaos":  # their -l is the supervisor's (checked there)
            check_transport(args)
        try:
            return args.func(args)
        except zenoh.ZError as exc:  # almost always: no router where --connect points
            if not (getattr(args, "creds", None) or getattr(args, "config", None)):
                from truav.bus.security import answers_tls
                for ep in getattr(args, "connect", None) or []:
                    if isinstance(ep, str) and answers_tls(ep):  # a --secure swarm's router, asked in plain TCP
                        raise UserError(f"-e/--connect {ep}: the router there speaks TLS (a --secure swarm) and "
                                        f"admits only clients with its credentials: pass --creds DIR (the run's "
                                        f"<out>/creds)") from None
            print(f"truav-swarm: error: Zenoh could not open a session ({str(exc).split(' at ')[0].strip()}); is a "
                  f"router running there? Start one with `truav-swarm router`, or pass -e/--connect ENDPOINT",
                  file=sys.stderr)
            return 1

    return run_main("truav-swarm", run, say_interrupted=False)


if __name__ == "__main__":
    sys.exit(main())

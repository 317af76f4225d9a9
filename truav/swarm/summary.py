"""The end of a swarm run: stop every process in an order that loses nothing, judge the run, write
summary.json and print the summary (truav.swarm.supervisor runs it)."""

from __future__ import annotations

import json
import os
import signal
import sys
from pathlib import Path

import numpy as np

from recorder.record_modes import parts_index_path, snapshot_path
from truav.analysis.agent_loader import AGENT_KIND_PREFIX
from truav.atomic import EXIT_NO_SPACE, write_kept
from truav.config import Config
from truav.stats import shown
from truav.swarm import external
from truav.swarm.children import exit_text
from truav.swarm.outdir import SUMMARY_FILE
from truav.swarm.references import references_for, references_line
from truav.swarm.ray_recovery import loss_entries, loss_lines
from truav.swarm.restart_cost import restart_costs, restart_lines
from truav.wire import keys
from truav.swarm.swarm_options import (AGENT_EXIT_GRACE_S, AGENT_STOP_TIMEOUT_S, DOWN_IDENTITY, RECORDER_STOP_TIMEOUT_S,
                                       ROUTER_STOP_TIMEOUT_S, SHUTDOWN_SENDERS, WORLD_STOP_TIMEOUT_S, Outcome,
                                       process_of)
from truav import jsonio
from truav.analysis.policy_scenario import Fit

CENTRAL_STATE_VALUES = 50
"""The paper's centralized baseline: each UAV uploads a 50-value state at 10 Hz."""
CENTRAL_VALUE_BYTES = 4


class SwarmEnd:
    """The end part of the supervisor's _Swarm (its state lives in _Swarm.__init__)."""

    def _shutdown(self, normal_end: bool) -> None:
        """Stop every process started, in an order that loses nothing (see the module docstring)."""
        children = self.children
        if self.controller is not None:
            self.controller.stop()
        pausable = [*self.fleet, "world", "recorder"]  # what a fault plan may freeze
        children.thaw(pausable)  # a frozen process must run to stop; SIGTERM alone would wait for ever
        if normal_end:
            children.wait_exit(self.fleet, AGENT_EXIT_GRACE_S)
        killed = children.stop(["world"], timeout=WORLD_STOP_TIMEOUT_S)
        children.thaw(pausable)  # the plan's last thaw may have been cancelled
        killed += children.stop(self.fleet, timeout=AGENT_STOP_TIMEOUT_S)
        for name in killed:
            self.outcome.fail(f"{name} did not stop within {AGENT_STOP_TIMEOUT_S:.0f} s of SIGTERM and was killed: "
                              f"its final checkpoint and statistics may be missing")
        if "recorder" in children.procs:
            if children.stop(["recorder"], sig=signal.SIGINT, timeout=RECORDER_STOP_TIMEOUT_S):
                self.outcome.fail(f"the recorder did not finish {self.opts.record} within "
                                  f"{RECORDER_STOP_TIMEOUT_S:.0f} s and was killed (try `truav log recover`)")
            elif children.procs["recorder"].returncode and not any("recorder" in f for f in self.outcome.failures):
                self.outcome.fail(f"the recorder failed to finish {self.opts.record} "
                                  f"({exit_text(children.procs['recorder'].returncode)}): "
                                  f"{children.last_line('recorder')}")
        others = [n for n in children.procs if n not in ("world", "recorder", "router", *self.fleet)]  # the viewer
        children.stop(others, timeout=WORLD_STOP_TIMEOUT_S)
        if "router" in children.procs:
            children.stop(["router"], timeout=ROUTER_STOP_TIMEOUT_S)
        children.close_logs()

    def _judge(self) -> None:
        """What ended the run, from what was seen; failures the watch could not see on its own."""
        o, opts = self.outcome, self.opts
        with self.monitor.lock:
            o.shutdowns = [(round(t - self.t0, 2), src) for t, src in self.monitor.shutdowns]
        foreign = [src for _, src in o.shutdowns if src != keys.SRC_WORLD]
        for src in dict.fromkeys(foreign):
            if src not in SHUTDOWN_SENDERS:
                o.fail(f"a shutdown came from an unknown sender {src!r}")
        world = _read_json(self.out / "world.json")
        done = len((world or {}).get("episodes") or [])
        full = [name for name in [*self.fleet, "world"]  # exited EXIT_NO_SPACE: their last log line may be missing
                if name in self.children.procs and self.children.procs[name].returncode == EXIT_NO_SPACE]
        if not o.ended_by:
            if foreign:
                first = foreign[0]
                o.ended_by = f"a shutdown from {first!r} ({SHUTDOWN_SENDERS.get(first, 'unknown sender')})"
                if first == DOWN_IDENTITY and done < opts.episodes:
                    o.interrupted_by = SHUTDOWN_SENDERS[first]
            elif done == opts.episodes:
                o.ended_by = f"the world finished its {done} episode(s) (shutdown from 'world')"
            elif "world" in full:
                o.ended_by = "the world's end (shutdown from 'world'; its statistics did not fit on the disk)"
            else:
                o.fail(f"the world stopped after {done} of {opts.episodes} episode(s)")
        if world and o.ticked:
            self._judge_missed(world, world.get("ticks", 0) - done)
        self._judge_parts()
        if full:
            o.fail(f"no space left on {self.out.absolute()}: {', '.join(full)} could not write {'its' if len(full) == 1 else 'their'} "
                   f"checkpoint or statistics (the last complete copies are kept; free space and --resume)")
        stalls = stall_text(world)
        if stalls and o.ticked:
            planned = any(f.kind == "freeze" and f.params.get("target") == "world"
                          for f in (self.plan.faults if self.plan else ()))
            if planned:  # the plan froze it: expected, but still said
                o.warnings.append(stalls)
            else:
                o.fail(stalls)
        killed_for_good = {process_of(f.params.get("target", f.params.get("uav")))
                           for f in (self.plan.faults if self.plan else ())
                           if f.kind == "crash" and "restart_after" not in f.params}
        logs = {f"agent{i}": name for ids, name in zip(self.groups, self.agents) for i in ids}  # uav -> its process
        for name in [*logs, *(["controller"] if self.central else [])]:
            if o.ticked and not (self.out / f"{name}.json").is_file() and name not in killed_for_good:
                o.warnings.append(f"{name} wrote no statistics (see {self.children.log_dir}/{logs.get(name, name)}.log)")
        if opts.lockstep and o.ticked:
            o.exactness = lockstep_exactness(world, [_read_json(self.out / f"{name}.json") for name in logs],
                                             _read_json(self.out / "controller.json") if self.central else None)
            if not o.exactness["exact"]:
                o.fail(inexact_text(o.exactness, opts.lockstep_wait_s))
        if opts.lockstep and o.restarts:
            o.warnings.append(f"{len(o.restarts)} restart(s) in a lock-step run: a restarted process resumed from its "
                              f"checkpoint while the world went on without it, so this run is not exactly a clean "
                              f"run of seed {opts.seed}")
        if opts.external:  # no process and no statistics of their own: the world's accounting of them
            o.external = [external.report(world, i, self.external_joined.get(i)) for i in opts.external]
            for entry in o.external:
                failures, warnings = external.verdicts(entry, world if o.ticked else None, opts.max_missed_share)
                for reason in failures:
                    o.fail(reason)
                o.warnings.extend(warnings)
        for loss in self.children.node_losses:  # a Ray node lost mid-run (truav.swarm.ray_recovery)
            what = f"Ray node {loss.node_id[:8]} ({loss.address}) was lost ({loss.cause})"
            if loss.refused:
                o.fail(f"{what}; its agents were not placed again: {loss.refused}", ends_run=False)
            else:
                o.warnings.append(f"{what}; its agents ({', '.join(loss.moved)}) were placed again on the nodes left "
                                  f"and resumed from their checkpoints")
        lost = ((world or {}).get("controller_losses") or []) if self.central else []
        if lost:
            o.warnings.append(f"the controller was lost at {', '.join(f'{t:g}' for t in lost)} s after tick 0; the "
                              f"UAVs held their last command for {opts.command_hold_s:g} s, then hovered "
                              f"(the world ran on)")

    def _planned_uavs(self) -> set[int]:
        """The UAVs whose process the fault plan crashes or freezes: their misses are the plan's, not the run's."""
        targets = {process_of(f.params.get("target", f.params.get("uav")))
                   for f in (self.plan.faults if self.plan else ()) if f.kind in ("crash", "freeze")}
        return {i for ids, name in zip(self.groups, self.agents) for i in ids
                if f"agent{i}" in targets or name in targets}

    def _judge_missed(self, world: dict, acting: int) -> None:
        """More than --max-missed of the actions missing degrades the run. The UAVs the plan crashes or freezes
        miss actions by design: their misses are said, and the limit judges the other UAVs' (all of them when the
        plan touches no agent, or when per-UAV counts are missing)."""
        o, opts = self.outcome, self.opts
        planned = self._planned_uavs()
        on_lost = {u for loss in self.children.node_losses for u in loss.uavs} - planned  # on a lost Ray node
        per_uav = {u.get("uav"): int(u.get("missed", 0)) for u in world.get("per_uav") or [] if isinstance(u, dict)}
        if acting <= 0:
            return
        if on_lost and per_uav:
            o.warnings.append(f"{sum(per_uav.get(i, 0) for i in on_lost)} action(s) missed by the UAV(s) of the lost "
                              f"Ray node(s) ({', '.join(map(str, sorted(on_lost)))}): the loss's cost, not held against "
                              f"--max-missed")
            planned = planned | on_lost
        if not planned or not per_uav:
            missed = 1.0 - world.get("actions_received", 0) / (acting * self.n)
        else:
            planned_missed = sum(per_uav.get(i, 0) for i in planned - on_lost)
            if planned - on_lost:
                o.warnings.append(f"{planned_missed} action(s) missed by the UAV(s) the fault plan crashes or freezes "
                                  f"({', '.join(map(str, sorted(planned - on_lost)))}): expected, not held against "
                                  f"--max-missed")
            others = self.n - len(planned)
            if others <= 0:
                return
            missed = sum(m for u, m in per_uav.items() if u not in planned) / (acting * others)
        if missed > opts.max_missed_share:
            self._degraded(missed_text(missed, opts.max_missed_share, *host_load(), cause=self._miss_cause()))

    def _miss_cause(self) -> str | None:
        """What made processes miss actions besides the host's load, if anything: the plan's crashes and pauses, a
        restart, an agent that exited."""
        kinds = sorted({f.kind for f in (self.plan.faults if self.plan else ()) if f.kind in ("crash", "freeze")})
        if kinds:
            return f"the fault plan's {' and '.join(kinds)} faults"
        if self.outcome.restarts:
            return f"{len(self.outcome.restarts)} process restart(s)"
        exited = [f.split(" ", 1)[0] for f in self.outcome.failures + self.outcome.warnings if " exited mid-run " in f]
        return f"{', '.join(exited)} down (exited mid-run)" if exited else None

    def _degraded(self, reason: str, tolerated: bool = False) -> None:
        """A run that went on degraded: a failure, or a warning if tolerated by its flag or if the run was
        interrupted (its exit code then says so: 130, 143, 129)."""
        if tolerated or self.outcome.interrupted_by:
            self.outcome.warnings.append(reason)
        else:
            self.outcome.fail(reason, ends_run=False)

    def _judge_parts(self) -> None:
        """A --agent class's failed calls, and agent processes (or the controller) that exited with an error at the
        end: failures, or warnings under --tolerate-agent-errors."""
        o, opts = self.outcome, self.opts
        tolerate = opts.tolerate_agent_errors
        if opts.scheme.startswith(AGENT_KIND_PREFIX):
            stats = [(i, _read_json(self.out / f"agent{i}.json")) for ids in self.groups for i in ids]
            o.agent_errors = {str(i): int(st.get("agent_errors") or 0) for i, st in stats
                              if isinstance(st, dict) and st.get("agent_errors")}
            if o.agent_errors:
                first = next(st for i, st in stats if str(i) in o.agent_errors)
                line = agent_errors_text(opts.scheme[len(AGENT_KIND_PREFIX):], o.agent_errors,
                                         first.get("first_agent_error"), int(first.get("uav", -1)), tolerate)
                self._degraded(line, tolerate)
        said = [*o.failures, *o.warnings]
        for name in self.fleet:
            p = self.children.procs.get(name)
            if p is None or p.returncode in (0, None, EXIT_NO_SPACE) or p.pid in self.planned_exits \
                    or any(text.startswith(name + " ") for text in said):  # told already (mid-run, killed)
                continue
            note = (f"{name} exited with an error at the end ({exit_text(p.returncode)}); its last log line: "
                    f"{self.children.last_line(name)}")
            self._degraded(note + (" (tolerated: --tolerate-agent-errors)" if tolerate else
                                   " (--tolerate-agent-errors to accept)"), tolerate)

    def _summary(self, elapsed: float) -> None:
        cfg, opts, out, monitor, o = self.cfg, self.opts, self.out, self.monitor, self.outcome
        world = _read_json(out / "world.json")
        agents = [_read_json(out / f"agent{i}.json") for i in range(self.n)]
        controller = _read_json(out / "controller.json") if self.central else None
        cp = monitor.control_plane()
        events = self.controller.events if self.controller is not None else []
        sent = self.controller.plans_sent if self.controller is not None else []
        with monitor.lock:
            timeline = {"coverage": list(monitor.coverage), "hovering": list(monitor.hovering)}
        with monitor.lock:
            costs = restart_costs(self.deaths, self.children.incarnations, monitor.live_up, monitor.step_times,
                                  monitor.missed_at, dict(zip(self.agents, self.groups)), monitor.t0)
        losses = loss_entries(list(self.children.node_losses), costs, self.t0_wall_ns)
        refs, no_refs = references_for(cfg, opts.scheme, opts.seed, world, opts.references) if o.ticked else (None, None)
        fit_line = Fit(**opts.policy_fit).line() if opts.policy_fit else None
        if fit_line and fit_line not in o.warnings:  # a mismatch the user allowed, or a record that is missing
            o.warnings.append(fit_line)
        outcome = {"result": o.result, "ended_by": o.ended_by, "interrupted_by": o.interrupted_by,
                   "lockstep": o.exactness, "restarts": o.restarts, "superseded": o.superseded,
                   "external": o.external, "agent_errors": o.agent_errors,
                   "failures": o.failures, "warnings": o.warnings, "shutdowns": o.shutdowns, "exit_code": o.exit_code()}
        summary = jsonio.dumps({
            "scheme": opts.scheme, "world": world, "agents": agents, "controller": controller,
            "control_plane": cp, "elapsed_s": elapsed, "federated": federated_traffic(cfg, world, agents, opts.rate_hz),
            "interrupted": o.interrupted_by is not None, "outcome": outcome, "endpoint": self.endpoint,
            "fault_events": events, "fault_plans_sent": sent, "timeline": timeline,
            "overrides": (world or {}).get("overrides") or [],
            "controller_incarnations": self.children.starts.get("controller", 0) if self.central else None,
            "processes": self.children.incarnation_stats(self.t0), "t0_wall_ns": self.t0_wall_ns,
            "router_outages_wall_ns": self.router_outages, "policy_scenario": opts.policy_fit,
            "restart_costs": costs, "node_losses": losses, "references": refs,
            # the agents' checkpoint steps (agents.process.agent_process.checkpoint_due): the chaos checker's
            "checkpoints": {"every_steps": opts.checkpoint_every, "uavs": cfg.scenario.n_uavs}}, indent=1).encode()
        write_kept(out / SUMMARY_FILE, lambda f: f.write(summary), o.fail)  # said with the result below
        if o.ticked:
            _print_results(cfg, opts, world, agents, cp, events, elapsed, o, sent)
            print(references_line(opts.scheme, world, refs, no_refs, bool(self.plan and self.plan.faults)))
            for entry in o.external:
                print(external.summary_line(entry))
            if self.central:
                _print_central(cfg, opts, world, agents, controller, cp, self.children.starts.get("controller", 1))
            if opts.plot and monitor.tracks:
                from truav.analysis.swarm_plots import swarm_figure
                picture = swarm_figure(cfg, monitor, out / "summary.png", title=f"swarm {opts.run!r}", plan=self.plan,
                                       episodes_done=len((world or {}).get("episodes") or []) if world else None,
                                       missed=(world or {}).get("deadline_misses"))
                print(f"picture: {picture}")
            if opts.record:
                print(f"recording: {recording_files(opts)}")
        for r in o.restarts:
            print(f"restarted {r['process']} at {r['restarted_s']:.1f} s (it died at {r['died_s']:.1f} s, "
                  f"{r['cause']}; restart {r['number']})")
        for line in restart_lines(costs):
            print(line)
        for line in loss_lines(losses):
            print(line)
        for note in o.warnings:
            print(f"warning: {note}")
        print(f"ended by: {o.ended_by}")
        if o.failures:
            print(f"result: FAILED ({'; '.join(o.failures)})", flush=True)
            print(f"truav-swarm: error: {o.failures[0]}", file=sys.stderr, flush=True)
        else:
            print(result_line(o), flush=True)


def result_line(o: Outcome) -> str:
    """The closing line of a run that did not fail: never a bare "ok" when warnings were printed above it."""
    if not o.warnings:
        return f"result: {o.result}"
    return f"result: {o.result}, with {len(o.warnings)} warning(s) above"


LOADED_SHARE = 1.0
"""The host counts as loaded (the likely cause of missed actions) when its 1-minute load average is at least
this many runnable processes per core."""


def host_load() -> tuple[float | None, int]:
    """(1-minute load average or None where the OS has none, cores this process may run on)."""
    try:
        load = os.getloadavg()[0]
    except OSError:
        load = None
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:
        cores = os.cpu_count() or 1
    return load, cores


def missed_text(share: float, limit: float, load: float | None, cores: int, cause: str | None = None) -> str:
    """The failure of a run that missed more than ``limit`` of its actions, naming ``cause`` (the run's own: its
    plan's crashes, an agent down) if any, else the host's load when it is at least LOADED_SHARE per core (then the
    likely cause)."""
    text = f"{100 * share:.0f}% of the actions were missing (more than --max-missed {limit:g})"
    if cause:
        text += f": {cause}, the likely cause"
    elif load is not None and load >= LOADED_SHARE * cores:
        text += (f": the host was loaded (load average {load:.1f} over the last minute on {cores} core(s), this "
                 f"swarm's processes included), the likely cause; a quieter host, a lower --rate or fewer --agents "
                 f"miss fewer")
    return text


AGENT_ERRORS_NAMED = 10
"""An agent-errors line names at most this many UAVs."""


def agent_errors_text(agent: str, errors: dict[str, int], first: str | None, first_uav: int, tolerated: bool) -> str:
    """One line: which UAVs' --agent class failed calls, how many, and the first message (its UAV hovered each)."""
    uavs = sorted(errors, key=int)
    named = ", ".join(uavs[:AGENT_ERRORS_NAMED]) + (f" and {len(uavs) - AGENT_ERRORS_NAMED} more"
                                                   if len(uavs) > AGENT_ERRORS_NAMED else "")
    return (f"agent class {agent} failed {sum(errors.values())} call(s) on uav {named} (each time its UAV hovered; "
            f"agent<i>.json agent_errors); first: {first or 'not recorded'} (uav {first_uav})"
            + ("; tolerated: --tolerate-agent-errors" if tolerated else "; --tolerate-agent-errors to accept"))


def stall_text(world: dict | None) -> str | None:
    """The world's stalls (world.process.world_process.STALL_MIN_S), in one line, or None."""
    stalls = (world or {}).get("stalls") or []
    if not stalls:
        return None
    named = ", ".join(f"{st['s']:.1f} s before tick {st['tick']} ({st['ticks_skipped']} tick(s) skipped)"
                      for st in stalls[:3])
    more = f" and {len(stalls) - 3} more" if len(stalls) > 3 else ""
    return (f"the world stalled {len(stalls)} time(s) (paused, or the host stalled): {named}{more}; it resumed "
            f"from the current time, the skipped ticks' actions were never asked for")


def _print_results(cfg, opts, world, agents, cp, events, elapsed, o: Outcome, sent: list[dict]) -> None:
    print(f"\n== swarm '{opts.run}' summary ({elapsed:.1f} s{', ' + o.result if o.result != 'ok' else ''}) ==")
    for e, m in enumerate((world or {}).get("episodes") or []):
        cov, pdr, delay, energy = (jsonio.num(m.get(k)) for k in ("coverage_pct", "pdr", "delay_ms", "energy_j"))
        print(f"episode {e}: coverage {shown(cov, '5.1f', '%')}  PDR {shown(pdr, '.3f')}  "
              f"delay {shown(delay, '6.1f', ' ms')}  energy/UAV {shown(energy / 1e3, '6.2f', ' kJ')}")
    if world:
        lat = world.get("tick_lateness_ms")
        if lat:
            print(f"tick lateness p50 {lat['p50']:.2f} ms, p99 {lat['p99']:.2f} ms over {lat['n']} ticks")
        late, stale = world.get("late_actions", 0), world.get("stale_actions", 0)
        print(f"ticks {world['ticks']}, actions received {world['actions_received']}, "
              f"missed (hovered) {world['deadline_misses']}"
              + (f" (answers that came late {late}, out of order {stale})" if late or stale else "")
              + f", agent losses seen {len(world['losses'])}"
              + (f" (reconnections of live agents not counted: {world['rejoins']})" if world.get("rejoins") else ""))
        if world.get("ticks_skipped"):
            print(f"tick periods skipped (the world resumed from the current time after starting late): "
                  f"{world['ticks_skipped']}")
    line = per_uav_line((world or {}).get("per_uav") or [])
    if line:
        print(line)
    ex = o.exactness
    if ex is not None:
        print("lock-step: exact (every live process was waited for)" if ex["exact"] else
              f"lock-step: NOT exact from tick {ex['inexact_from_tick']}: {ex['decisions_without_peer']} decision(s) "
              f"without a live peer's message, {ex['world_went_on_without']} answer(s) the world went on without")
    rejected = rejection_summary(world, agents)
    if rejected:
        print(rejected)
    lat = [a["beacon_latency_ms"] for a in agents if a and a.get("beacon_latency_ms", {}).get("n")]
    if lat:
        print(f"beacon one-way latency: p50 {np.median([x['p50'] for x in lat]):.2f} ms, "
              f"p99 {np.max([x['p99'] for x in lat]):.2f} ms (worst agent)")
    if cp["beacons"]:
        n = cfg.scenario.n_uavs
        central = n * CENTRAL_STATE_VALUES * opts.rate_hz
        print(f"control plane: {cp['bytes_per_beacon']:.0f} B/beacon, {cp['beacons_per_s_per_uav']:.1f} beacons/s per UAV, "
              f"{cp['beacon_bytes_per_s_total'] / 1e3:.1f} kB/s in total; a centralized critic would upload "
              f"{n} x {CENTRAL_STATE_VALUES} values x {opts.rate_hz:g} Hz = {central:,.0f} values/s "
              f"({central * CENTRAL_VALUE_BYTES / 1e3:.1f} kB/s of float32) to one controller")
    fed = federated_traffic(cfg, world, agents, opts.rate_hz)
    if fed is not None:
        central = central_model_bytes_per_s(cfg, opts.rate_hz)
        print(f"federated TRUAV (every {cfg.federated.every} episode(s)): {fed['shares_sent']} shares in "
              f"{fed['messages_sent']} messages, {fed['rows_sent']} Q rows, {fed['bytes_sent']:,} B sent = "
              f"{fed['bytes_per_uav_per_s']:.1f} B/s per UAV at {opts.rate_hz:g} ticks/s ({fed['ticks']} ticks), "
              f"beside the centralized control plane's {central / cfg.scenario.n_uavs:,.0f} B/s per UAV "
              f"({central / 1e3:.1f} kB/s for {cfg.scenario.n_uavs} UAVs, modelled); merged {fed['shares_merged']} "
              f"peer shares, refused {sum(fed['refused'].values())}, waited out {fed['missing']}")
    lines = [(p["t_s"], f"fault plan sent to the live run at {p['t_s']:.1f} s by {p['src']}: {p['link_faults']} link "
                        f"fault(s) replace the run's (summary.json fault_plans_sent)") for p in sent]
    lines += [(t, f"fault {kind} {phase} at {t:.1f} s") for t, kind, phase in events]  # after a plan sent at once
    for _, line in sorted(lines, key=lambda tl: tl[0]):
        print(line)
    for line in override_lines(world):
        print(line)


def override_lines(world: dict | None) -> list[str]:
    """One line per UAV steered from outside (world.json overrides; summary.json overrides)."""
    out = []
    for o in (world or {}).get("overrides") or []:
        if o.get("phase") == "start":
            out.append(f"override: UAV {o.get('uav')} steered by {o.get('by')} from tick {o.get('tick')} to "
                       f"({jsonio.num(o.get('x')):.0f}, {jsonio.num(o.get('y')):.0f}) m (summary.json overrides)")
        else:
            out.append(f"override: UAV {o.get('uav')} released by {o.get('by')} at tick {o.get('tick')}")
    still = (world or {}).get("overridden_at_end") or []
    if still:
        out.append(f"override: UAV(s) {', '.join(map(str, still))} still steered from outside when the run ended")
    return out


def federated_traffic(cfg: Config, world, agents, rate_hz: float) -> dict | None:
    """Federated TRUAV's Q-share traffic summed over the agents' stats files, and per UAV per second at
    ``rate_hz`` ticks a second (the world's ticks / rate_hz: as the centralized control plane's bytes per
    second are counted; in lock-step a nominal rate); None without sharing."""
    stats = [a["federated"] for a in agents if a and a.get("federated")]
    if not stats:
        return None
    total = {k: sum(s[k] for s in stats) for k in ("shares_sent", "messages_sent", "bytes_sent", "rows_sent",
                                                    "shares_merged", "missing")}
    refused: dict[str, int] = {}
    for s in stats:
        for reason, n in s["refused"].items():
            refused[reason] = refused.get(reason, 0) + n
    ticks = (world or {}).get("ticks") or 0
    per_uav = total["bytes_sent"] / cfg.scenario.n_uavs / (ticks / rate_hz) if ticks else float("nan")
    return {**total, "refused": refused, "ticks": ticks, "rate_hz": rate_hz, "bytes_per_uav_per_s": per_uav}


def lockstep_exactness(world, agents, controller) -> dict:
    """Lock-step: whether every process waited for every live peer (the run is then exact), else how many
    decisions were taken without a live process's message, and from which tick (the earliest)."""
    world_missed = int((world or {}).get("lockstep_missed", 0))
    ticks = [(world or {}).get("lockstep_missed_from_tick")]
    per_agent: dict[str, int] = {}
    for stats in agents:
        ls = (stats or {}).get("lockstep") or {}
        if ls.get("decisions_without_peer"):
            per_agent[f"agent{stats.get('uav')}"] = int(ls["decisions_without_peer"])
            ticks.append(ls.get("inexact_from_tick"))
    ctl = ((controller or {}).get("lockstep") or {})
    ctl_missed = int(ctl.get("decisions_without_peer", 0))
    ticks.append(ctl.get("inexact_from_tick"))
    ticks = [t for t in ticks if t is not None]
    decisions = sum(per_agent.values()) + ctl_missed
    return {"exact": not (world_missed or decisions), "decisions_without_peer": decisions,
            "by_agent": per_agent, "controller_decisions_without_peer": ctl_missed,
            "world_went_on_without": world_missed, "inexact_from_tick": min(ticks) if ticks else None}


def inexact_text(ex: dict, wait_s: float) -> str:
    parts = []
    if ex["decisions_without_peer"]:
        who = [f"{a} {n}" for a, n in ex["by_agent"].items()]
        who += [f"controller {ex['controller_decisions_without_peer']}"] if ex["controller_decisions_without_peer"] else []
        parts.append(f"{ex['decisions_without_peer']} decision(s) taken without a live peer's message ({', '.join(who)})")
    if ex["world_went_on_without"]:
        parts.append(f"the world went on without {ex['world_went_on_without']} live agent answer(s)")
    return (f"lock-step is no longer exact from tick {ex['inexact_from_tick']} (a live process did not answer within "
            f"--lockstep-wait {wait_s:g} s; a longer one waits out longer pauses): {'; '.join(parts)}")


def central_model_bytes_per_s(cfg: Config, rate_hz: float) -> float:
    """What the in-process control-plane model sends per second of real time: every UAV's upload and
    command each round (agents.central.ControlPlaneModel.messages), rate_hz / update_period rounds."""
    c = cfg.central
    up_m, up_b, down_m, down_b = cfg.scenario.n_uavs, cfg.scenario.n_uavs * c.upload_bytes, \
        cfg.scenario.n_uavs, cfg.scenario.n_uavs * c.download_bytes
    return (up_b + down_b) * rate_hz / c.update_period_steps


def _print_central(cfg, opts, world, agents, controller, cp, incarnations: int = 1) -> None:
    c = cfg.central
    model = central_model_bytes_per_s(cfg, opts.rate_hz)
    ctl = controller or {}
    policy = ctl.get('policy', opts.policy or 'learning online')
    own = (f"{ctl.get('ticks', 0)} tick(s) decided, {ctl.get('commands', 0)} command(s) sent, "
           f"{ctl.get('stale_states', 0)} missing upload(s) filled from the last one"
           + (f", decision p99 {ctl['decide_ms']['p99']:.1f} ms" if ctl.get("decide_ms") else ""))
    if incarnations > 1:  # a crashed incarnation writes no statistics: the bus counts every one's commands
        print(f"controller ({policy}), {incarnations} incarnations: commands for {cp.get('command_ticks', 0)} tick(s), "
              f"{cp.get('commands', 0)} command(s) heard on the bus; the last incarnation: {own}")
    else:
        print(f"controller ({policy}): {own}")
    counts = {"fresh": 0, "held": 0, "hovered": 0}
    for a in agents:
        for k, v in ((a or {}).get("commands") or {}).items():
            counts[k] = counts.get(k, 0) + v
    print(f"UAVs flew a fresh command {counts['fresh']} time(s), held the last one {counts['held']}, hovered without "
          f"one {counts['hovered']} (hold {opts.command_hold_s:g} s)")
    if cp.get("states") or cp.get("commands"):
        if opts.lockstep:
            rate = "lock-step: per second of wall time, not of the world's"
        else:
            rate = f"model at {opts.rate_hz:g} Hz: {model / 1e3:.1f} kB/s"
        print(f"control plane measured on the bus: {cp['states']} uploads x {cp['bytes_per_state']:.0f} B + "
              f"{cp['commands']} commands x {cp['bytes_per_command']:.0f} B = "
              f"{cp['central_bytes_per_s'] / 1e3:.1f} kB/s; the in-process model: {cfg.scenario.n_uavs} x "
              f"({c.upload_bytes} + {c.download_bytes}) B per round = "
              f"{cfg.scenario.n_uavs * (c.upload_bytes + c.download_bytes):,} B ({rate})")
    eps = (world or {}).get("episodes") or []
    if eps and "ctrl_delay_ms" in eps[0]:
        print(f"modelled radio effects applied by the world: action delay {np.mean([e['ctrl_delay_ms'] for e in eps]):.1f}"
              f" ms, control airtime {np.mean([e['ctrl_airtime_s'] for e in eps]):.2f} s/UAV/episode "
              f"({np.mean([e['ctrl_energy_j'] for e in eps]):.1f} J)")




PER_UAV_SHOWN = 10
"""The summary names at most this many UAVs (the worst) that missed or were refused anything."""


def per_uav_line(per_uav: list[dict]) -> str:
    """One line: the UAVs with anything missed, late, stale or rejected, worst first (at most PER_UAV_SHOWN),
    as "uav <i> missed <m>[, late ..][, rejected <reason> <n>]"; "" when every UAV is clean."""
    def bad(u):
        return u.get("missed", 0) + u.get("late", 0) + u.get("stale", 0) + sum((u.get("rejected") or {}).values())
    worst = sorted((u for u in per_uav if bad(u)), key=lambda u: (-bad(u), u["uav"]))
    if not worst:
        return ""
    parts = []
    for u in worst[:PER_UAV_SHOWN]:
        counts = [f"{k} {u[k]}" for k in ("missed", "late", "stale") if u.get(k)]
        counts += [f"rejected {r} {n}" for r, n in sorted((u.get("rejected") or {}).items())]
        parts.append(f"uav {u['uav']} " + " ".join(counts))
    more = len(worst) - PER_UAV_SHOWN
    return (f"per UAV ({len(worst)} of {len(per_uav)} with misses or refusals, worst first): " + "; ".join(parts)
            + (f"; and {more} more (world.json per_uav)" if more > 0 else ""))


def rejection_summary(world, agents) -> str:
    """One line: how many messages the world and the agents refused, by reason (truav.wire.guard)."""
    by_reason: dict[str, int] = {}
    for stats in [(world or {}).get("rejected") or {}] + [((a or {}).get("bus") or {}).get("rejected") or {}
                                                          for a in agents]:
        for reason, senders in stats.items():
            by_reason[reason] = by_reason.get(reason, 0) + sum(senders.values())
    if not by_reason:
        return ""
    return (f"rejected messages (world + agents): {sum(by_reason.values())} ("
            + ", ".join(f"{r} {n}" for r, n in sorted(by_reason.items())) + "); see world.json / agent<i>.json")


def _read_json(path: Path):
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def recording_files(opts) -> str:
    """Where `up --record` wrote: the file, or its parts' index, or its snapshots' pattern."""
    modes = opts.record_modes
    if modes.split:
        return f"parts listed in {parts_index_path(Path(opts.record))}"
    if modes.snapshot is not None:
        return f"snapshots {snapshot_path(Path(opts.record), 1)} ... (none if nothing triggered one)"
    return str(opts.record)

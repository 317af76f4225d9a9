"""What a swarm run is given (:class:`SwarmOptions`) and how it ended (:class:`Outcome`), with the
supervisor's timing constants and the names of its agent processes."""

from __future__ import annotations

import signal
from dataclasses import dataclass, field
from pathlib import Path

from agents.process.agent_options import AgentOptions
from agents.process.controller_options import ControllerOptions
from recorder.record_modes import RecordModes
from truav.analysis.agent_loader import AGENT_KIND_PREFIX
from truav.config import Config
from truav.faults import FaultPlan
from truav.lifecycle import DEFAULT_ROUTER_TIMEOUT_S
from truav.options import opt
from truav.stopping import exit_code_for
from truav.swarm.external import DEFAULT_EXTERNAL_WAIT_S
from truav.swarm.healing import DEFAULT_RESTART_LIMIT, DEFAULT_RESTART_POLICY
from truav.wire import keys
from truav.wire.schema import DEFAULT_LOCKSTEP_WAIT_S
from world.process.world_options import WorldOptions

DOWN_IDENTITY = "supervisor"
"""The sender of `truav-swarm down`'s shutdown request."""
SHUTDOWN_SENDERS = {keys.SRC_WORLD: "the world, after its last episode", DOWN_IDENTITY: "`truav-swarm down`"}
"""Senders whose shutdown is expected; one from anyone else fails the run (and names the sender)."""

DEMO_AGENT = "ppo-claim"
"""What `truav-swarm up` flies when given neither --scheme nor --agent (the README's command 1): the learned
decentralized policy cloned from the climbing heuristic (agents.ppo_agent.PpoClaimAgent, numpy weights shipped with
the project). In the demo's scenario (the defaults with 1.5 km sensing, 2 episodes from random starts; seeds 0-29,
greedy, in process by truav.analysis.trainer.run_chunk) it covered 31.1%, +3.2 ± 1.6 points above ppo's 27.9%
(paired 95% interval), level with the heuristic claim it was cloned from (31.1%, -0.0 ± 0.5), +4.5 ± 1.8 above the
heuristic spread's 26.6% and twice hover's 14.2%, where TRUAV's Q-learners learning from scratch cover what hover
does. ``--scheme truav`` learns from scratch."""
DEMO_SCHEME = AGENT_KIND_PREFIX + DEMO_AGENT
SENSING_AGENTS = ("spread", "claim", "ppo", "ppo-claim", "ppo-disc")
"""Built-in agent classes designed (spread, claim) or trained (ppo, ppo-claim) with sensing on: `up` flies them with
learner.sense_range_m at agents.spread_agent.SENSE_RANGE_M where the scenario leaves sensing off (and ppo-disc with
learner.sense_disc on: agents.spread_agent.with_sensing)."""

STATUS_PERIOD_S = 1.0
ROUTER_START_TIMEOUT_S = 15.0
RECORDER_START_TIMEOUT_S = 30.0
AGENT_EXIT_GRACE_S = 5.0
"""Normal end: agents leave by themselves on the world's shutdown; SIGTERM after this long."""
AGENT_STOP_TIMEOUT_S = 30.0
"""After SIGTERM an agent writes its final checkpoint and statistics (an fsync each); SIGKILL after this long."""
WORLD_STOP_TIMEOUT_S = 15.0
RECORDER_STOP_TIMEOUT_S = 90.0
"""The recorder writes its backlog and footer (its writer alone may take 60 s), then rewrites the
file into big chunks (seconds per 10 MB); SIGKILL after this long."""
ROUTER_STOP_TIMEOUT_S = 5.0
ROUTER_RECONNECT_WAIT_S = 10.0
"""After restarting the router: how long the supervisor waits for its own session to reconnect."""
RSS_PERIOD_S = 5.0
"""How often the supervisor samples its children's memory (summary.json "processes")."""


@dataclass
class SwarmOptions:
    """How `truav-swarm up` runs a swarm; what it passes down to a process defaults as that process's
    options declare (WorldOptions, AgentOptions, ControllerOptions)."""

    run: str = "demo"
    seed: int = 0
    episodes: int = WorldOptions.episodes
    lockstep: bool = False
    lockstep_wait_s: float = DEFAULT_LOCKSTEP_WAIT_S
    """Lock-step: how long world and agents wait for a live process before the run gives up exactness."""
    rate_hz: float = WorldOptions.rate_hz
    record: str | None = None
    record_modes: RecordModes = field(default_factory=RecordModes)
    """With ``record``: one file, parts (split by size, time, command) or snapshots (recorder.record_modes)."""
    qtable: str | None = None
    greedy: bool = False
    policy_fit: dict | None = None
    """How the --qtable/--policy fits the scenario it was trained in (truav.analysis.policy_scenario.Fit.as_json):
    summary.json records it, and the summary says a mismatch the user allowed or a record that is missing."""
    out: str | None = None
    """Where the run's files go; None: :attr:`out_dir`'s default, runs/swarm-<run>."""
    listen: str | None = None
    plot: bool = True
    quiet: bool = False
    wait_agents_s: float = 60.0
    checkpoint_every: int = 50
    """Agents checkpoint their Q-table every this many steps."""
    verbose: bool = False
    """Children log at DEBUG level too; each process's start is printed."""
    fault_plan: str | None = None
    """Fault plan TOML (truav.faults): link faults applied by every process,
    crashes and freezes sent by this supervisor."""
    plan: FaultPlan | None = None
    """``fault_plan`` already parsed (by the command line's check): the run uses it instead of reading
    the file again, so a plan is parsed once per process."""
    resume: bool = False
    """Continue the run already in ``out`` (agents resume from its checkpoints); else ``out`` must be empty."""
    force: bool = False
    """Delete an earlier run's files in ``out`` first, and overwrite ``record``."""
    max_missed_share: float = WorldOptions.max_missed_share
    """The run fails when more than this share of the actions the world waited for did not come."""
    tolerate_agent_errors: bool = opt(False, flag="--tolerate-agent-errors", action="store_true",
                                      help="end ok (with a warning) although a --agent class failed calls (raised, "
                                           "returned an illegal action, took too long) or an agent process exited "
                                           "with an error and stayed down; without it either fails the run")
    """A --agent class's failed calls (its UAV hovered those ticks) and agent processes that exited with an error and
    were not restarted are warnings, not failures."""
    router_timeout_s: float = DEFAULT_ROUTER_TIMEOUT_S
    """World and agents stop by themselves this long after losing their router."""
    foxglove_port: int | None = None
    """Serve the run to the Foxglove app on ws://127.0.0.1:<port> (`truav-swarm view`)."""
    geo_origin: tuple[float, float] | None = None
    """(lat, lon) of the area's centre on Foxglove's map (recorder and view); None: Paris."""
    secure: bool = False
    """Mutual TLS and the router's access control, with fresh credentials in <out>/creds (truav.bus.security)."""
    scheme: str = "truav"
    """truav (Q-learning agents) | central (a controller process commands every UAV) | patrol (the plan) |
    agent:NAME (an agents.api class; the command line's default is :data:`DEMO_SCHEME`)."""
    policy: str | None = None
    """Scheme central: the trained controller to fly (`truav train --scheme central` run); None: learn online."""
    policy_index: int = ControllerOptions.policy_index
    command_hold_s: float = AgentOptions.command_hold_s
    """Scheme central: how long a UAV keeps its last command once commands stop, then hovers."""
    snapshot_every: int = WorldOptions.snapshot_every
    """Recorded lock-step runs: the world and every agent publish their state every this many ticks (0: never)."""
    beacon_every: int = AgentOptions.beacon_every
    """Real time: agents beacon every this many ticks (10 at 10 Hz: 1 Hz, the Remote ID rate)."""
    beacon_cell_m: float | None = AgentOptions.beacon_cell_m
    """Real time: range-limited beacons under map cells of this side (agents/beacon_cells.py); None: all-to-all."""
    beacon_slots: int = AgentOptions.beacon_slots
    """Real time: the swarm's beacons go out in this many send slots per tick (agents/beacon_schedule.py)."""
    agents_per_process: int = 1
    """Agents hosted by one OS process, each with its own session, identity and files (fewer processes:
    less memory and start-up for a large swarm). Fault plans that kill or freeze agents need 1."""
    share_beacons: bool = False
    """With agents_per_process > 1: one beacon subscription per process, decoded once for its agents."""
    batch_beacons: bool = False
    """Lock-step, agents_per_process > 1: each process sends its agents' beacons of a tick as one message."""
    restart: str = DEFAULT_RESTART_POLICY
    """on-failure: restart an agent, the controller or the router that dies on its own (truav.swarm.healing); never."""
    restart_limit: int = DEFAULT_RESTART_LIMIT
    """Restarts of one process before it is left down and the run fails."""
    external: tuple[int, ...] = ()
    """UAVs flown by the user's own agent, not started here (truav.swarm.external)."""
    external_wait_s: float = DEFAULT_EXTERNAL_WAIT_S
    references: bool = True
    """At the end, hover and patrol flown in process on the same scenario, seed and episodes (truav.swarm.references)."""
    """How long to wait for the external UAVs' liveliness tokens before tick 0; past it the run fails."""

    @property
    def out_dir(self) -> Path:
        """The run's directory: ``out``, or runs/swarm-<run> by default."""
        return Path(self.out) if self.out else default_out_dir(self.run)


def with_agent_sensing(scheme: str, cfg: Config) -> Config:
    """The config a swarm of ``scheme`` flies: sensing on for SENSING_AGENTS where ``cfg`` leaves it off."""
    from agents.spread_agent import SENSE_RANGE_M, with_sensing
    named = scheme[len(AGENT_KIND_PREFIX):] if scheme.startswith(AGENT_KIND_PREFIX) else None
    if named in SENSING_AGENTS and cfg.learner.sense_range_m == 0.0:
        cfg = cfg.replace(learner={"sense_range_m": SENSE_RANGE_M})
    return with_sensing(named, cfg) if named else cfg


def agent_groups(n: int, per_process: int, external: tuple[int, ...] = ()) -> list[list[int]]:
    """UAV ids 0..n-1 in consecutive groups of ``per_process``, one process each; ``external`` UAVs
    (flown by an agent not started here) are left out of their group, and a group left empty has no process."""
    groups = [[i for i in range(a, min(a + per_process, n)) if i not in external] for a in range(0, n, per_process)]
    return [g for g in groups if g]


def group_name(ids: list[int]) -> str:
    """The process name (log file, pids.json) of a group: ``agent3`` alone, ``agents0-9`` for several
    (``agents0,1,3`` when an external UAV left a gap)."""
    if len(ids) == 1:
        return f"agent{ids[0]}"
    return f"agents{ids[0]}-{ids[-1]}" if ids[-1] - ids[0] == len(ids) - 1 else "agents" + ",".join(map(str, ids))


@dataclass
class Outcome:
    """How a run ended: what ended it, what went wrong, what the user should know."""

    ended_by: str = ""
    interrupted_by: str | None = None  # Ctrl-C, SIGTERM, SIGHUP or `truav-swarm down`
    failures: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    shutdowns: list[tuple[float, str]] = field(default_factory=list)  # (s since start, sender)
    ticked: bool = False
    exactness: dict | None = None  # lock-step only: see lockstep_exactness
    restarts: list[dict] = field(default_factory=list)  # truav.swarm.healing.Restart.as_dict(), in order
    external: list[dict] = field(default_factory=list)  # truav.swarm.external.report() of each external UAV
    agent_errors: dict[str, int] = field(default_factory=dict)
    """A --agent class's failed calls by UAV id (as a string: summary.json's keys), from the agents' statistics."""
    superseded: list[dict] = field(default_factory=list)
    """Processes started again at once, not a fault: {"process", "pid", "cause"} (a router that lost the default
    port to another process between the check and its bind, started again on a free port)."""

    def fail(self, reason: str, ends_run: bool = True) -> None:
        """The run failed for ``reason``; ``ends_run``: that is also what ended it (unless something did before)."""
        if reason not in self.failures:
            self.failures.append(reason)
        if ends_run:
            self.ended_by = self.ended_by or reason

    @property
    def result(self) -> str:
        return "failed" if self.failures else "interrupted" if self.interrupted_by else "ok"

    def exit_code(self) -> int:
        if self.failures:
            return 1
        if not self.interrupted_by:
            return 0
        return {"SIGTERM": exit_code_for(signal.SIGTERM), "SIGHUP": exit_code_for(signal.SIGHUP)}.get(self.interrupted_by, 130)


def default_out_dir(run: str) -> Path:
    """Where `truav-swarm up --run RUN` writes without --out."""
    return Path(f"runs/swarm-{run}")


def process_of(who) -> str:
    """The supervisor's name of a fault plan's process: agent<i> for a UAV id, else the target's name."""
    return who if isinstance(who, str) else f"agent{who}"

"""How one agent process runs (AgentOptions, its flags declared with it), and the testing-only delay of an agent:
light to import (no kernels, no Zenoh), so that building the `truav-swarm agent` parser and the supervisor's child
command lines costs no more than it must."""

from __future__ import annotations

from dataclasses import dataclass

from agents.process.agent_process_realtime import REALTIME_BEACON_MAX_AGE_TICKS
from truav.options import opt
from truav.wire.schema import DEFAULT_LOCKSTEP_WAIT_S
from truav.wire.snapshot_messages import snapshot_every_option

DELAY_ENV = "TRUAV_AGENT_DELAY_MS"
"""Testing only: ``UAV:MS[,UAV:MS...]`` makes those agents pause MS ms per observation (see debug_delay_s)."""


def debug_delay_s(spec: str, uav: int) -> float:
    """The pause of agent ``uav`` from a DELAY_ENV value ("" for none); ValueError if malformed."""
    for item in filter(None, (part.strip() for part in spec.split(","))):
        who, sep, ms = item.partition(":")
        try:
            who_id, delay_ms = int(who), float(ms)
        except ValueError:
            who_id, delay_ms = -1, -1.0
        if not sep or who_id < 0 or not 0 <= delay_ms < 60_000:
            raise ValueError(f"{DELAY_ENV}={spec!r}: expected UAV:MS[,UAV:MS...] with 0 <= MS < 60000")
        if who_id == uav:
            return delay_ms / 1e3
    return 0.0


@dataclass
class AgentOptions:
    """How one agent process runs."""

    run: str = "demo"
    uav: int = 0
    seed: int = 0
    """Seed of the run: the agent draws from seeding.agent_rng(seed, uav)."""
    lockstep: bool = False
    lockstep_wait_s: float = DEFAULT_LOCKSTEP_WAIT_S
    """Lock-step: wait this long for a live peer's beacon (one heard since it joined; a peer not heard yet:
    LOCKSTEP_JOIN_GRACE_S) before deciding without it, which the stats count: the run is then not exact."""
    train: bool = True
    """Learn online (epsilon-greedy + updates); False acts greedily and never updates."""
    snapshot_every: int = snapshot_every_option()
    """Lock-step: publish this agent's decision state (agents.decision_state) at the ticks the world
    snapshots (divisible by this; 0: never)."""
    checkpoint: str | None = opt(None, flag="--checkpoint", metavar="FILE",
                                 help="Q-table checkpoint (.npz): resume from it, rewrite it")
    """Q-table checkpoint file (.npz): resumed from if it exists, rewritten every checkpoint_every steps."""
    checkpoint_every: int = opt(100, flag="--checkpoint-every", type="positive_int",
                                help="steps between checkpoints (default 100)")
    """K: UAV i checkpoints when (steps + i * K // n_uavs) % K == 0, so a swarm's writes are spread out."""
    qtable: str | None = opt(None, flag="--qtable", metavar="RUN", help="start from a trained run's Q-table")
    """Start from a trained run's qtables.npz (or run dir): the table of `qtable_index`, this UAV."""
    qtable_index: int = opt(0, flag="--qtable-index", type="non_negative_int",
                            help="which seed's table of that run (default 0)")
    beacon_phase: float = 0.3
    """Real time: beacons go out this fraction of the tick period after the
    tick starts, after the burst of observation deliveries and decisions..."""
    beacon_spread: float = 0.6
    """...in ``beacon_slots`` slots spread over this fraction of the period (agents.beacon_schedule)."""
    beacon_slots: int = opt(1, flag="--beacon-slots", type="positive_int", metavar="N",
                            help="real time: the swarm's beacons go out in N slots of the tick, UAV i in slot "
                                 "i %% N (default 1: together, so each receiver wakes once for them all)")
    """Real time: distinct beacon send times per tick (agents.beacon_schedule): 1 sends every beacon of a tick
    together, which Zenoh batches and a receiver takes in one wake-up; the number of UAVs gives each its own."""
    tick_period_s: float = 0.1
    fault_plan: str | None = None
    """Fault plan (TOML) whose link faults apply to what this agent receives."""
    accept_replay: bool = False
    """Act on traffic a replay puts into this run (dropped and counted by default)."""
    stats_out: str | None = opt(None, flag="--stats-out", metavar="FILE",
                                help="write beacon latency statistics as JSON at exit")
    debug_delay_s: float = 0.0
    """Testing only: pause this long per observation between sending the beacon and reading the peers'
    (a deliberately slow agent: lock-step results must not change)."""
    scheme: str = "truav"
    """truav (this class) | patrol | central (agents.process.scheme_process): what flies the UAV."""
    command_hold_s: float = opt(1.0, flag="--command-hold", type="non_negative_float", metavar="S",
                                help="--scheme central: without a fresh command a UAV keeps its last one this many "
                                     "seconds (world clock), then hovers (default 1)")
    """Scheme central: without a fresh command, keep flying the last one for this long (s of the
    world's clock, from the tick it was for), then hover: what an autopilot does when its link stops."""
    command_wait_frac: float = 0.5
    """Scheme central, real time: wait for the tick's command until this fraction of the tick period
    after the world stamped the observation (the world takes actions until deadline_frac, 0.8: the rest is for the action to get there on a busy host)."""
    beacon_every: int = opt(1, flag="--beacon-every", type="positive_int", metavar="TICKS",
                            help="real time: send a beacon every TICKS ticks, offset by id (10 at 10 Hz: 1 Hz, the "
                                 "Remote ID rate; default 1)")
    """Real time: send a beacon every this many ticks, offset by id (10 at 10 Hz: the Remote ID rate, 1 Hz)."""
    beacon_cell_m: float | None = opt(None, flag="--beacon-cell", type="positive_float", metavar="M",
                                      help="real time: range-limited beacons under map cells of M metres; hear only "
                                           "cells within range (agents/beacon_cells.py; default: all-to-all)")
    """Real time: range-limited beacons, under map cells of this side (agents.beacon_cells); None: all-to-all."""

    def __post_init__(self) -> None:
        if self.beacon_every < 1:
            raise ValueError(f"beacon_every must be >= 1, got {self.beacon_every}")
        if self.lockstep and (self.beacon_every != 1 or self.beacon_cell_m is not None):
            raise ValueError("lock-step waits for every live peer's beacon of each tick: "
                             "beacon_every and beacon_cell_m are for real time only")

    @property
    def beacon_max_age_ticks(self) -> int:
        """Real time: a neighbour's freshest beacon older than this is ignored (two intervals at a low rate)."""
        return max(REALTIME_BEACON_MAX_AGE_TICKS, 2 * self.beacon_every)


__all__ = ["DELAY_ENV", "AgentOptions", "debug_delay_s"]

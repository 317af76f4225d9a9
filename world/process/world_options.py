"""How the world process runs (WorldOptions, its flags declared with it): light to import (no kernels, no Zenoh),
so that building the `truav-swarm world` parser and the supervisor's child command lines costs no more than it must."""

from __future__ import annotations

from dataclasses import dataclass

from truav.options import opt
from truav.wire.schema import DEFAULT_LOCKSTEP_WAIT_S
from truav.wire.snapshot_messages import snapshot_every_option


@dataclass
class WorldOptions:
    """How the world process runs (scenario parameters live in Config)."""

    run: str = "demo"
    """Run name: every key lives under truav/<run>/."""
    seed: int = 0
    """World seed (same stream as the in-process trainer's world for this seed)."""
    episodes: int = opt(2, flag="--episodes", type="positive_int")
    """Episodes to run before publishing shutdown and exiting."""
    lockstep: bool = False
    """Wait for every live agent's action each tick (deterministic) instead of real time."""
    lockstep_wait_s: float = DEFAULT_LOCKSTEP_WAIT_S
    """Lock-step still never stalls forever: a live agent silent this long is skipped (it hovers, and the
    run is no longer exact: counted in WorldStats.lockstep_missed), and marked silent: later rounds do not
    wait for it until an action or acknowledgement of it (for any tick) comes again. So a live agent that
    answers nothing costs one such wait, not one per tick."""
    snapshot_every: int = snapshot_every_option()
    """Lock-step: publish the world's whole state (world.world_state) before every tick divisible by this
    (0: never); the supervisor passes 0 unless the run is recorded."""
    rate_hz: float = opt(10.0, flag="--rate", type="positive_float")
    """Real-time tick rate."""
    deadline_frac: float = 0.8
    """Real time: actions must arrive within this fraction of the tick period."""
    wait_agents_s: float = opt(30.0, flag="--wait-agents", type="positive_float",
                               help="seconds to wait for all agents (default 30)")
    """Before the first tick, wait up to this long for all n_uavs agents to be alive."""
    stats_out: str | None = opt(None, flag="--stats-out", metavar="FILE",
                                help="write per-episode metrics and timing as JSON")
    """Write per-episode metrics and timing statistics as JSON here at exit."""
    max_missed_share: float = opt(0.05, flag="--max-missed", type="share", metavar="SHARE",
                                  help="fail (exit 1) when more than this share of the actions is missing: no "
                                       "action applied in time, the UAV hovered (default 0.05; 1 tolerates any)")
    """More than this share of the actions missing (world_stats.missed_share) fails the run: `truav-swarm up`
    says so in its result (naming the host's load when it is the likely cause), a world exits
    world_host.EXIT_TOO_MANY_MISSED. A few percent: a quiet host misses (almost) none."""
    fault_plan: str | None = None
    """Fault plan (TOML) whose link faults apply to what this process receives."""
    accept_replay: bool = False
    """Act on traffic a replay puts into this run (dropped and counted by default)."""
    scheme: str = "truav"
    """truav | patrol | central. Under central the world also waits for the controller before
    tick 0 and, on every control round, applies the in-process control-plane model's radio
    effects (agents.central.ControlCounters: airtime of the uploads and commands, action delay):
    they happen on the simulated radio, which loopback messages do not cross."""


__all__ = ["WorldOptions"]

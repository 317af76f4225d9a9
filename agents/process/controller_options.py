"""How the central scheme's controller process runs (ControllerOptions, its flags declared with it): light to
import (no kernels, no Zenoh), so that building the `truav-swarm controller` parser costs no more than it must."""

from __future__ import annotations

from dataclasses import dataclass

from truav.options import opt
from truav.wire.schema import DEFAULT_LOCKSTEP_WAIT_S


@dataclass
class ControllerOptions:
    """How the controller process runs (the scenario lives in Config)."""

    run: str = "demo"
    seed: int = 0
    """Seed of the run: the SAC draws from seeding.baseline_rng(seed, 1), as the in-process driver's."""
    lockstep: bool = False
    lockstep_wait_s: float = DEFAULT_LOCKSTEP_WAIT_S
    """Lock-step: a live UAV silent this long is decided without (counted: the run is then not exact)."""
    policy: str | None = opt(None, flag="--policy", metavar="RUN",
                             help="--scheme central: fly this trained controller (`truav train --scheme central` "
                                  "output); default: learn online")
    """A `truav train --scheme central` run (or its policy.npz) whose actor is flown greedily; None: learn online."""
    policy_index: int = opt(0, flag="--policy-index", type="non_negative_int",
                            help="which seed's policy of that run (default 0)")
    tick_period_s: float = 0.1
    collect_frac: float = 0.3
    """Real time: decide a tick this fraction of the period after its first upload, if some are still missing."""
    stats_out: str | None = opt(None, flag="--stats-out", metavar="FILE",
                                help="write the controller's statistics as JSON at exit")
    fault_plan: str | None = None
    """Fault plan (TOML) whose link faults apply to what the controller receives (its uplink)."""
    accept_replay: bool = False


__all__ = ["ControllerOptions"]

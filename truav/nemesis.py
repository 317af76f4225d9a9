"""The random nemesis of `truav-swarm chaos --nemesis random`: a seeded schedule of faults.

Jepsen's nemesis, as a fault plan (truav.faults): every 5-15 s (uniform) one
of agent crashes (SIGKILL, restarted 2-6 s later from its checkpoint), pauses
(SIGSTOP for 1-6 s, then SIGCONT) of an agent, the world, the recorder (when
recording) or the controller (scheme central), a controller crash (scheme
central), a router kill (restarted 0.5-2 s later on its endpoint), and the
link faults: loss, latency, observation loss and partitions, 3-12 s each.
Every fault ends by :func:`heal_at`: the last :func:`quiet_tail_s` seconds
(a minute, or a third of a shorter run) are quiet, so the checker can see the
swarm recover.  A process is never hit twice at once, nor within
:data:`RESTART_SETTLE_S` of its restart.

Pure computation: a numpy Generator seeded with ``seed`` draws everything, so
the same arguments give the same plan, and the plan written to a file gives
the same schedule when run again with ``--plan`` (times rounded to 0.1 s,
which a TOML file holds exactly).
"""

from __future__ import annotations

import numpy as np

from truav.faults import CONTROLLER, RECORDER, ROUTER, WORLD, Fault, FaultPlan, plan_from_dict

NEMESES = ("random",)
FIRST_FAULT_S = (5.0, 10.0)
"""The first fault falls in this window after tick 0 (the swarm settles first)."""
GAP_S = (5.0, 15.0)
"""Between one fault's start and the next."""
QUIET_TAIL_S = 60.0
QUIET_SHARE = 1 / 3
PAUSE_S = (1.0, 6.0)
CRASH_RESTART_S = (2.0, 6.0)
ROUTER_RESTART_S = (0.5, 2.0)
LINK_S = (3.0, 12.0)
RESTART_SETTLE_S = 10.0
"""A crashed process is left alone this long after its restart (it loads, resumes and rejoins first)."""
MIN_FAULT_S = 1.0
"""A fault that would have to end sooner than this before the heal is not scheduled."""

WEIGHTS = {"crash": 3.0, "pause": 2.0, "pause_world": 1.0, "pause_recorder": 1.0, "pause_controller": 1.0,
           "crash_controller": 1.0, "router": 1.0, "loss": 1.5, "latency": 1.5, "obs_loss": 1.5, "partition": 1.5}
"""How often each move is drawn, relative to the others (among those this swarm has)."""


def quiet_tail_s(duration_s: float) -> float:
    """The quiet end of a run of ``duration_s``: no fault is active there."""
    return min(QUIET_TAIL_S, QUIET_SHARE * duration_s)


def heal_at(duration_s: float) -> float:
    """When every fault has ended, in seconds after tick 0."""
    return duration_s - quiet_tail_s(duration_s)


def _r(x: float) -> float:
    return round(float(x), 1)


def random_plan(duration_s: float, n_uavs: int, seed: int, *, central: bool = False,
                recording: bool = False) -> FaultPlan:
    """The random nemesis's plan for a run of ``duration_s`` seconds of ``n_uavs`` agents."""
    rng = np.random.default_rng(seed)
    heal = heal_at(duration_s)
    moves = [m for m in WEIGHTS if (central or "controller" not in m) and (recording or m != "pause_recorder")
             and (n_uavs >= 2 or m != "partition")]
    weights = np.array([WEIGHTS[m] for m in moves])
    busy: dict[str, float] = {}  # process -> until when a fault holds it
    faults: list[Fault] = []
    t = _r(rng.uniform(*FIRST_FAULT_S))
    while t + MIN_FAULT_S <= heal:
        move = moves[int(rng.choice(len(moves), p=weights / weights.sum()))]
        fault = _draw(move, rng, t, heal, n_uavs, busy)
        if fault is not None:
            faults.append(fault)
        t = _r(t + rng.uniform(*GAP_S))
    return plan_from_dict(FaultPlan(tuple(faults), seed).to_dict())  # validated, as a plan file is


def _draw(move: str, rng: np.random.Generator, t: float, heal: float, n: int,
          busy: dict[str, float]) -> Fault | None:
    def until(lo_hi: tuple[float, float]) -> float:  # a length from lo_hi, cut at the heal
        return _r(min(rng.uniform(*lo_hi), heal - t))

    def free(name: str) -> bool:
        return busy.get(name, -1.0) <= t

    if move in ("crash", "pause"):
        agents = [i for i in range(n) if free(f"agent{i}")]
        if not agents:
            return None
        uav = int(rng.choice(agents))
        length = until(CRASH_RESTART_S if move == "crash" else PAUSE_S)
        busy[f"agent{uav}"] = t + length + (RESTART_SETTLE_S if move == "crash" else 0.0)
        if move == "crash":
            return Fault("crash", t, params={"uav": uav, "restart_after": length})
        return Fault("freeze", t, length, {"uav": uav})
    if move.startswith("pause_"):
        target = {"pause_world": WORLD, "pause_recorder": RECORDER, "pause_controller": CONTROLLER}[move]
        if not free(target):
            return None
        length = until(PAUSE_S)
        busy[target] = t + length
        return Fault("freeze", t, length, {"target": target})
    if move in ("crash_controller", "router"):
        target = CONTROLLER if move == "crash_controller" else ROUTER
        if not free(target):
            return None
        length = until(CRASH_RESTART_S if target == CONTROLLER else ROUTER_RESTART_S)
        busy[target] = t + length + RESTART_SETTLE_S
        return Fault("crash", t, params={"target": target, "restart_after": length})
    length = until(LINK_S)
    if move == "loss":
        keys = str(rng.choice(["uav/*/beacon", "uav/*/action", "**"]))
        return Fault("loss", t, length, {"probability": round(float(rng.uniform(0.1, 0.5)), 2), "keys": keys})
    if move == "latency":
        keys = str(rng.choice(["uav/*/beacon", "uav/*/obs", "uav/*/action"]))
        return Fault("latency", t, length, {"fixed_ms": _r(rng.uniform(20.0, 150.0)),
                                            "jitter_ms": _r(rng.uniform(0.0, 50.0)), "keys": keys})
    if move == "obs_loss":
        return Fault("obs_loss", t, length, {"probability": round(float(rng.uniform(0.1, 0.5)), 2)})
    order = [int(u) for u in rng.permutation(n)]  # partition: two non-empty groups
    cut = int(rng.integers(1, n))
    return Fault("partition", t, length, {"groups": [sorted(order[:cut]), sorted(order[cut:])]})

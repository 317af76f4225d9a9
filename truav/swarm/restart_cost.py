"""What a restart cost, phase by phase (`truav-swarm up`'s summary and summary.json "restart_costs").

A crashed agent misses more ticks than its time down: after the supervisor starts it again, the new
process imports, loads its checkpoint and warms up before it joins the bus, and only then answers the
world's next observation. Each restart (the fault plan's crash with ``restart_after``, or a death the
healer restarts) is split into three phases, each with the ticks its UAV(s) missed in it:

``down``      the process's death (the plan's kill, or the death seen) to its restart;
``starting``  the restart to the new process's liveliness token (it is on the bus, ready to act);
``joining``   the liveliness token to the first tick the world got its action(s) for.

All times are the supervisor's (monotonic clock); a tick counts in the phase its step metrics
arrived in (their ``uav.<i>.missed`` totals, which the world publishes each tick).
"""

from __future__ import annotations

import bisect

PHASES = ("down", "starting", "joining")
MAX_DEATHS = 1000
"""Deaths the supervisor keeps for this account (a restart limit keeps them far fewer)."""


def _count(times: list[tuple[float, int]], start: float, end: float) -> int:
    """Missed ticks whose step arrived in [start, end)."""
    return sum(n for t, n in times if start <= t < end)


def restart_costs(deaths: list[tuple[str, float]], incarnations: list[tuple[str, object, float]],
                  live_up: dict[str, list[float]], step_times: list[float],
                  missed_at: dict[int, list[tuple[float, int]]], uavs_of: dict[str, list[int]],
                  t0: float | None) -> list[dict]:
    """One entry per death of an agent process: its phases' lengths (s, None when the run ended first)
    and the ticks its UAVs missed in each. ``deaths``: (process, monotonic time); ``incarnations``:
    (process, proc, started monotonic) as truav.swarm.children keeps them; ``live_up``: liveliness
    identity (``uav/<i>``) -> monotonic times its token appeared; ``step_times``: arrival of each step's
    metrics (sorted); ``missed_at``: UAV -> (arrival, ticks missed) of the steps it missed."""
    out = []
    origin = t0 if t0 is not None else min((t for _, t in deaths), default=0.0)
    for k, (name, died) in enumerate(deaths):
        uavs = uavs_of.get(name)
        if not uavs:  # the router, the controller: no UAV's ticks to count
            continue
        later = [t for n, t in deaths[k + 1:] if n == name]
        horizon = later[0] if later else float("inf")  # the next death of the same process ends this account
        restarted = min((s for n, _, s in incarnations if n == name and died <= s < horizon), default=None)
        live = None if restarted is None else \
            min((t for t in live_up.get(f"uav/{uavs[0]}", []) if restarted <= t < horizon), default=None)
        acted = None
        if live is not None:
            missed_times = {t for u in uavs for t, _ in missed_at.get(u, [])}
            i = bisect.bisect_left(step_times, live)
            while i < len(step_times) and step_times[i] < horizon:
                if step_times[i] not in missed_times:
                    acted = step_times[i]
                    break
                i += 1
        bounds = [died, restarted, live, acted]
        entry: dict = {"process": name, "uavs": list(uavs), "died_s": round(died - origin, 2)}
        missed_total = 0
        for p, phase in enumerate(PHASES):
            start, end = bounds[p], bounds[p + 1]
            if start is None:
                entry[f"{phase}_s"], entry[f"missed_{phase}"] = None, None
                continue
            stop = end if end is not None else horizon
            n = sum(_count(missed_at.get(u, []), start, stop) for u in uavs)
            entry[f"{phase}_s"] = None if end is None else round(end - start, 2)
            entry[f"missed_{phase}"] = n
            missed_total += n
        entry["missed_total"] = missed_total
        entry["to_first_action_s"] = None if acted is None or restarted is None else round(acted - restarted, 2)
        out.append(entry)
    return out


PHASE_WORDS = {"down": "down (death to restart)", "starting": "starting (restart to its liveliness token)",
               "joining": "joining (token to its first action)"}


def _phase(entry: dict, phase: str) -> str:
    s, n = entry[f"{phase}_s"], entry[f"missed_{phase}"]
    if n is None:
        return f"{PHASE_WORDS[phase]} not reached"
    took = f"{s:.1f} s" if s is not None else "not over by the end"
    return f"{PHASE_WORDS[phase]} {took}, {n} missed"


def restart_lines(costs: list[dict]) -> list[str]:
    """Per restart: where its missed ticks went (a heading line and one line per phase)."""
    lines = []
    for c in costs:
        who = ", ".join(f"UAV {u}" for u in c["uavs"][:4]) + (" ..." if len(c["uavs"]) > 4 else "")
        lines.append(f"restart of {c['process']} ({who}; died at {c['died_s']:.1f} s) cost {c['missed_total']} "
                     f"missed tick(s): " + "; ".join(_phase(c, p) for p in PHASES))
    return lines

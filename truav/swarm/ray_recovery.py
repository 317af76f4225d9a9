"""A Ray node lost mid-run (`truav-swarm up --ray`): its agents placed again on the nodes left.

A node is lost when Ray declares it dead (its raylet stopped or was cut off), or when its router's process
is gone (its Ray worker processes were killed: the node is up, but its agents would have no router to reach).
Its processes then count as crashed: the supervisor's healer (truav.swarm.healing) restarts each agent
process after its backoff, through truav.swarm.ray_swarm.RayChildren's spawn hook, which asks
:meth:`NodeRecovery.plan_for` first: the first restart that finds its node lost re-plans without it
(truav.swarm.ray_plan.without_node: the least loaded nodes left take its agents), and every agent of the lost
node starts on its new node, connected to that node's router, resuming from its checkpoint (the run's
directory is shared by the nodes). The core node (the world's, the recorder's and the first router's) cannot
be lost: the run ends there, as it would on one host. Under --secure a lost node's agents are not placed
again: their keys lived on that node only (the run fails, saying so).

Each loss is kept as a :class:`NodeLoss`; the summary (truav.swarm.summary) turns it into summary.json's
``node_losses`` (:func:`loss_entries`, with the restarts' costs: outage seconds and actions missed) and the
closing lines (:func:`loss_lines`). No Ray here: the Ray calls are ray_swarm's.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

from truav.swarm.children import exit_text
from truav.swarm.ray_plan import PlanError, RayPlan, without_node


@dataclass
class NodeLoss:
    """One lost node: when it was first seen gone, why, and where its agent processes went."""

    node_id: str
    address: str
    cause: str  # "its Ray node died", "its router's process died (killed by SIGKILL)"
    lost_wall_ns: int  # the first of its processes seen gone (wall clock, as the recordings' log times)
    replanned_wall_ns: int
    moved: dict[str, str] = field(default_factory=dict)  # agent process -> its new node
    uavs: list[int] = field(default_factory=list)
    refused: str | None = None  # why its agents were not placed again (then the run fails)
    deaths_before: dict[str, int] = field(default_factory=dict)  # agent process -> its deaths before this one


class NodeRecovery:
    """The nodes lost so far, and the plan the next start goes by (held by RayChildren)."""

    def __init__(self, alive_nodes: Callable[[], set[str]], secure: bool = False, say=print):
        self.alive_nodes = alive_nodes  # the ids of the cluster's alive nodes (ray_swarm asks Ray)
        self.secure = secure
        self.say = say
        self.losses: list[NodeLoss] = []

    def plan_for(self, children, name: str) -> RayPlan:
        """The plan to (re)start ``name`` by: ``children.plan``, or once its node is found lost, the plan without
        that node (kept as ``children.plan`` from then on)."""
        plan: RayPlan = children.plan
        if not children.starts.get(name) or name not in {a.name for a in plan.agents}:
            return plan  # a first start, or not an agent: placed by the plan as it stands
        node = plan.node_of(name)
        if node == plan.core_node or any(loss.node_id == node for loss in self.losses):
            return plan
        cause = self._lost(children, plan, node)
        if cause is None:
            return plan
        address = next(n.address for n in plan.nodes if n.node_id == node)
        ended = [p.ended_wall_ns for a in plan.agents if a.node_id == node
                 for p in [children.procs.get(a.name)] if getattr(p, "ended_wall_ns", None)]
        loss = NodeLoss(node, address, cause, min(ended, default=time.time_ns()), time.time_ns(),
                        uavs=[u for a in plan.agents if a.node_id == node for u in a.uavs])
        loss.deaths_before = {a.name: children.starts.get(a.name, 1) - 1 for a in plan.agents if a.node_id == node}
        self.losses.append(loss)
        if self.secure:
            loss.refused = "under --secure its agents' keys lived on that node only"
            self.say(f"Ray node {node[:8]} ({address}) lost ({cause}); its agents are not placed again: "
                     f"{loss.refused}", flush=True)
            return plan
        try:
            new, loss.moved = without_node(plan, node)
        except PlanError as exc:
            loss.refused = str(exc)
            return plan
        children.plan = new
        self.say(f"Ray node {node[:8]} ({address}) lost ({cause}); its agents placed again: "
                 + ", ".join(f"{a} -> node {n[:8]}" for a, n in loss.moved.items()), flush=True)
        return new

    def _lost(self, children, plan: RayPlan, node: str) -> str | None:
        """Why ``node`` can no longer host the run's processes; None if it can."""
        if node not in self.alive_nodes():
            return "its Ray node died"
        router = next(r for r in plan.routers if r.node_id == node)
        proc = children.procs.get(router.name)
        if proc is not None and proc.poll() is not None:
            return f"its router's process died ({exit_text(proc.returncode)}); the node is up"
        return None


def loss_entries(losses: list[NodeLoss], costs: list[dict], t0_wall_ns: int) -> list[dict]:
    """summary.json's ``node_losses``: per lost node, its id, address, cause, time (s since the supervisor's
    start), the agents moved (process -> node), its UAVs, and from the restarts' costs
    (truav.swarm.restart_cost) of those agents' first restart after the loss: the outage (s from the loss to
    the last of them acting again; None if one never did) and the actions its UAVs missed meanwhile."""
    out = []
    for loss in losses:
        lost_s = (loss.lost_wall_ns - t0_wall_ns) / 1e9
        mine, seen = {}, {}
        for c in costs:  # in order of deaths: each moved process's death that came with the loss
            name = c["process"]
            if name in loss.moved and seen.setdefault(name, 0) == loss.deaths_before[name]:
                mine[name] = c
            seen[name] = seen.get(name, 0) + 1
        back = [c["to_first_action_s"] for c in mine.values()]
        outage = None
        if mine and len(mine) == len(loss.moved) and all(b is not None for b in back):
            outage = round(max(c["down_s"] + b for c, b in zip(mine.values(), back)), 2)
        out.append({"node_id": loss.node_id, "address": loss.address, "cause": loss.cause,
                    "lost_s": round(lost_s, 2), "lost_wall_ns": loss.lost_wall_ns,
                    "agents_moved": dict(loss.moved), "uavs": list(loss.uavs),
                    "outage_s": outage, "missed_actions": sum(c["missed_total"] for c in mine.values()),
                    "refused": loss.refused})
    return out


def loss_lines(entries: list[dict]) -> list[str]:
    """The summary's lines: each lost node named, with where its agents went and what the loss cost."""
    lines = []
    for e in entries:
        head = f"Ray node {e['node_id'][:8]} ({e['address']}) lost at {e['lost_s']:.1f} s ({e['cause']})"
        if e["refused"]:
            lines.append(f"{head}: its agents were not placed again ({e['refused']})")
            continue
        where = ", ".join(f"{a} -> node {n[:8]}" for a, n in e["agents_moved"].items())
        took = f"{e['outage_s']:.1f} s outage" if e["outage_s"] is not None else "outage not over by the end"
        lines.append(f"{head}: {where}, resumed from their checkpoints; {took}, "
                     f"{e['missed_actions']} action(s) missed by its {len(e['uavs'])} UAV(s)")
    return lines

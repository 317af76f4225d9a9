"""Where a swarm's processes run on a Ray cluster: a pure plan (no Ray, no I/O).

One Zenoh router per node, each linked to the first node's router (the core node, which also
hosts the world, the recorder, the controller and the supervisor's own session); the agent
processes (the run's groups of ``--agents-per-process`` UAVs, truav.swarm.swarm_options.agent_groups)
dealt to the nodes in turn, so their counts differ by at most one. Every process connects only to
its node's router, as in the hand-made deployment (deploy/README.md). Nodes that share an address
(a test cluster on one machine) get consecutive ports.
"""

from __future__ import annotations

from dataclasses import dataclass

from truav.bus.acl import CONTROLLER, RECORDER, SUPERVISOR, VIEW, WORLD
from truav.bus.secure_configs import Site
from truav.swarm.swarm_options import agent_groups, group_name
from truav.wire.keys import uav_identity

CORE_PROCESSES = ("world", "recorder", "controller", "view")
"""The processes of the core node (the first router's node)."""
CORE_IDENTITIES = (WORLD, RECORDER, SUPERVISOR, CONTROLLER, VIEW)
"""Under --secure, the identities whose keys go to the core node (its processes and the supervisor's session)."""


class PlanError(ValueError):
    """The cluster or the options cannot hold the swarm (one line for the user)."""


@dataclass(frozen=True)
class RayNode:
    node_id: str
    address: str
    cpus: float


@dataclass(frozen=True)
class RouterPlace:
    node_id: str
    endpoint: str
    connect: str | None  # the core router it links to; None for the core router itself

    @property
    def name(self) -> str:
        return "router" if self.connect is None else f"router-{self.node_id[:8]}"


@dataclass(frozen=True)
class AgentPlace:
    node_id: str
    uavs: tuple[int, ...]

    @property
    def name(self) -> str:
        return group_name(list(self.uavs))


@dataclass(frozen=True)
class RayPlan:
    nodes: tuple[RayNode, ...]
    routers: tuple[RouterPlace, ...]
    agents: tuple[AgentPlace, ...]

    @property
    def core_node(self) -> str:
        return self.routers[0].node_id

    @property
    def core_endpoint(self) -> str:
        return self.routers[0].endpoint

    def node_of(self, process: str) -> str:
        """The node of a process by its name (the supervisor's names: world, agent3, agents0-9, router...)."""
        for place in (*self.routers, *self.agents):
            if place.name == process:
                return place.node_id
        return self.core_node

    def endpoint_of(self, process: str) -> str:
        """The router endpoint a process connects to: its node's."""
        node = self.node_of(process)
        return next(r.endpoint for r in self.routers if r.node_id == node)

    def sites(self) -> tuple[Site, ...]:
        """Under --secure, the plan as a router-per-host deployment (truav.bus.secure_configs.Site): node k's
        router is ``router/node<k>`` on its endpoint; each node holds only its processes' identities."""
        out = []
        for k, router in enumerate(self.routers):
            host, _, port = router.endpoint.split("/", 1)[1].rpartition(":")
            ids = [uav_identity(u) for a in self.agents if a.node_id == router.node_id for u in a.uavs]
            out.append(Site(f"node{k}", host.strip("[]"), int(port), (*(CORE_IDENTITIES if k == 0 else ()), *ids)))
        return tuple(out)

    def lines(self, secure: bool = False) -> list[str]:
        """What runs where; ``secure``: the routers' TLS endpoints, linked in a full mesh (their configs')."""
        out = []
        for k, (node, router) in enumerate(zip(self.nodes, self.routers)):
            shown = [f"tls/{r.endpoint.split('/', 1)[1]}" if secure else r.endpoint for r in self.routers[:k + 1]]
            links = ", ".join(shown[:-1]) if secure else router.connect
            parts = [f"router {shown[-1]}" + (f" -> {links}" if links else "")]
            parts += ["world", "recorder"] if k == 0 else []
            parts += [a.name for a in self.agents if a.node_id == node.node_id]
            out.append(f"node {node.node_id} ({node.address}): " + ", ".join(parts))
        return out


def place(nodes: list[RayNode], n_uavs: int, agents_per_process: int, port: int,
          external: tuple[int, ...] = ()) -> RayPlan:
    """The plan for ``nodes`` (the first is the core node) and the run's options; PlanError if it cannot be."""
    if not nodes:
        raise PlanError("--ray: the cluster has no alive Ray node")
    seen: dict[str, int] = {}
    routers = []
    for node in nodes:
        offset = seen.get(node.address, 0)
        seen[node.address] = offset + 1
        if not 0 < port + offset <= 65535:
            raise PlanError(f"--ray-port {port}: the routers' ports {port}..{port + offset} must lie in 1..65535")
        host = f"[{node.address}]" if ":" in node.address else node.address
        endpoint = f"tcp/{host}:{port + offset}"
        routers.append(RouterPlace(node.node_id, endpoint, routers[0].endpoint if routers else None))
    groups = agent_groups(n_uavs, agents_per_process, external)
    agents = tuple(AgentPlace(nodes[k % len(nodes)].node_id, tuple(g)) for k, g in enumerate(groups))
    return RayPlan(tuple(nodes), tuple(routers), agents)


def without_node(plan: RayPlan, lost: str) -> tuple[RayPlan, dict[str, str]]:
    """The plan once node ``lost`` is gone, and the agent processes it moves (name -> new node): the node and
    its router leave the plan; each of its agent processes, in plan order, goes to the node left holding the
    fewest (ties: the earlier node in the plan); nothing else moves. PlanError if ``lost`` is the core node
    (the world's and the recorder's, which the run cannot survive) or not in the plan."""
    if lost == plan.core_node:
        raise PlanError(f"node {lost} holds the world and the recorder: the run cannot survive its loss")
    if lost not in {n.node_id for n in plan.nodes}:
        raise PlanError(f"node {lost} is not in the plan")
    nodes = tuple(n for n in plan.nodes if n.node_id != lost)
    load = {n.node_id: sum(a.node_id == n.node_id for a in plan.agents) for n in nodes}
    order = {n.node_id: k for k, n in enumerate(nodes)}
    agents, moved = [], {}
    for a in plan.agents:
        if a.node_id == lost:
            target = min(load, key=lambda node: (load[node], order[node]))
            load[target] += 1
            moved[a.name] = target
            a = AgentPlace(target, a.uavs)
        agents.append(a)
    routers = tuple(r for r in plan.routers if r.node_id != lost)
    return RayPlan(nodes, routers, tuple(agents)), moved

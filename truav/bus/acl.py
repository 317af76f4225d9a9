"""Who may do what on a locked bus: the one table of grants and Zenoh's ``access_control`` section.

:func:`grants` says, for each identity (``world``, ``uav/<i>``, ``recorder``, ``supervisor``, ``replay``,
``controller``, ``view``, ``operator``), the keys it may put, the key expressions it may subscribe to, the liveliness
tokens it may declare and those it may watch; :func:`acl_config` turns that table into Zenoh's
``access_control`` section (default deny, subjects are certificate common names) and :func:`explain`
into lines for ``truav-swarm acl explain``. How Zenoh applies it: :mod:`truav.bus.security`.
"""

from __future__ import annotations

import fnmatch
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from truav.wire import keys, schema_names

ROUTER = "router"
WORLD = keys.SRC_WORLD
RECORDER = keys.SRC_RECORDER
SUPERVISOR = "supervisor"
REPLAY = keys.SRC_REPLAY
CONTROLLER = keys.SRC_CONTROLLER  # the central scheme's controller (agents.process.central_process)
VIEW = "view"  # the Foxglove bridge (truav.swarm.view)
OPERATOR = keys.SRC_OPERATOR  # steers a UAV from outside (truav-swarm steer, the MAVLink bridge's repositions)

REPLAY_RUN_SUFFIX = "-replay"


class CredentialsError(ValueError):
    """A credentials directory that is missing, incomplete or made for another run."""


# --- the one table -----------------------------------------------------------------------------
@dataclass(frozen=True)
class Grant:
    """What one identity may do on the bus (full key expressions)."""

    identity: str
    """The sender id and certificate common name: ``world``, ``uav/<i>``, ``recorder`` ..."""
    put: tuple[str, ...] = ()
    """Keys it may put on (and whose subscribers it may learn of)."""
    subscribe: tuple[str, ...] = ()
    """Key expressions it may subscribe to; the router forwards it only puts on these."""
    tokens: tuple[str, ...] = ()
    """Liveliness tokens it may declare."""
    watch: tuple[str, ...] = ()
    """Liveliness key expressions it may watch or query."""
    serve: tuple[str, ...] = ()
    """Keys it may declare a queryable on and answer (a replay's ``replay/ctl``)."""
    ask: tuple[str, ...] = ()
    """Keys it may query (and get the answers of)."""



def replay_run(run: str) -> str:
    """The run a replay publishes into under --secure: its own, next to the live one."""
    return keys.validate_run(run + REPLAY_RUN_SUFFIX)


def batch_groups(n_uavs: int, group_size: int) -> list[tuple[int, int]]:
    """(first, last) of each process's UAVs when ``group_size`` agents share a process (the layout of
    truav.swarm.swarm_options.agent_groups): consecutive ids; a group of one sends no batches."""
    if group_size <= 1:
        return []
    groups = [(a, min(a + group_size, n_uavs) - 1) for a in range(0, n_uavs, group_size)]
    return [(a, b) for a, b in groups if b > a]


def grants(run: str, n_uavs: int, batch_group_size: int = 1) -> tuple[Grant, ...]:
    """Who may put / subscribe where in run ``run`` with ``n_uavs`` agents (docs/explanation/security.md).

    ``batch_group_size`` > 1 (``--batch-beacons`` with that many agents per process): the first UAV of each
    process's group may put that group's batch of beacons (``group/<first>-<last>/beacons``), and only it."""
    p = keys.prefix(run)
    r = keys.prefix(replay_run(run))
    table = [
        Grant(WORLD,
              put=(f"{p}/world/*", keys.all_obs(run), keys.all_metrics(run), keys.all_rejected(run),
                   # The world announces the end of the run: its only control key.
                   keys.control(run, "shutdown"),
                   # and when a UAV steered from outside starts and ends (control/override/<i>)
                   keys.fault(run, schema_names.FAULT_OVERRIDE)),
              subscribe=(keys.all_actions(run), keys.all_control(run), keys.world_tick(run)),
              tokens=(keys.alive_world(run),), watch=(keys.all_alive_uavs(run), keys.alive_controller(run))),
        # Scheme central: every UAV's state upload in, one command per UAV out.
        Grant(CONTROLLER, put=(keys.all_commands(run),),
              subscribe=(keys.all_states(run), keys.all_control(run), keys.world_tick(run)),
              tokens=(keys.alive_controller(run),), watch=(keys.all_alive_uavs(run),)),
        Grant(RECORDER, subscribe=(keys.everything(run),), tokens=(keys.alive_recorder(run),),
              watch=(keys.all_alive(run),)),
        Grant(SUPERVISOR,
              put=(keys.all_control(run), keys.all_faults(run), keys.control(replay_run(run), "replay")),
              subscribe=(keys.all_metrics(run), f"{p}/world/*", keys.all_beacons(run), keys.all_beacons_in_cells(run),
                         *([keys.all_beacon_batches(run)] if batch_group_size > 1 else []),
                         keys.all_control(run), keys.all_states(run), keys.all_commands(run),  # traffic measured for the summary
                         keys.all_health(run),  # the agents' health reports, for `status`
                         keys.replay_status(replay_run(run))),  # a replay's position (replay-ctl)
              watch=(keys.all_alive(run),), ask=(keys.replay_ctl(replay_run(run)),)),
        Grant(VIEW, subscribe=(keys.everything(run),)),
        # Steers a UAV from outside: only the override keys (the supervisor may too, through control/**), and
        # hears the world's confirmation.
        Grant(OPERATOR, put=(keys.all_overrides(run),), subscribe=(keys.fault(run, schema_names.FAULT_OVERRIDE),),
              watch=(keys.all_alive(run),)),
        # The replay publishes into its own run; it takes commands there (control/replay, the ctl queryable)
        # and, under --lockstep, hears the live agents' answers and tokens of that run.
        Grant(REPLAY, put=(f"{r}/**",),
              subscribe=(keys.control(replay_run(run), "replay"), keys.all_actions(replay_run(run))),
              tokens=(), watch=(keys.all_alive_uavs(replay_run(run)),), serve=(keys.replay_ctl(replay_run(run)),)),
    ]
    batches = {first: keys.group_beacons(run, first, last) for first, last in batch_groups(n_uavs, batch_group_size)}
    for i in range(n_uavs):
        table.append(Grant(
            keys.uav_identity(i),
            put=(keys.uav_beacon(run, i), f"{keys.uav_beacon(run, i)}/*", keys.uav_action(run, i), keys.uav_state(run, i),
                 keys.uav_health(run, i), keys.uav_snapshot(run, i), keys.uav_qshares(run, i), *([batches[i]] if i in batches else [])),
            subscribe=(keys.uav_obs(run, i), keys.uav_rejected(run, i), keys.all_beacons(run), keys.all_beacons_in_cells(run), keys.world_tick(run),
                       keys.all_control(run), keys.controller_cmd(run, i), keys.all_qshares(run),
                       *([keys.all_beacon_batches(run)] if batches else [])),
            tokens=(keys.alive_uav(run, i),), watch=(keys.all_alive_uavs(run), keys.alive_controller(run))))
    return tuple(table)


def component_names(n_uavs: int) -> tuple[str, ...]:
    """File stems of the credentials: router, world, ..., uav-0, uav-1, ..."""
    return (ROUTER, WORLD, RECORDER, SUPERVISOR, VIEW, OPERATOR, REPLAY, CONTROLLER, *(file_stem(keys.uav_identity(i)) for i in range(n_uavs)))


def file_stem(identity: str) -> str:
    """``uav/3`` -> ``uav-3`` (file names cannot hold a slash)."""
    return identity.replace("/", "-")


# --- Zenoh's access_control section -------------------------------------------------------------
def _rule(rid: str, messages: Sequence[str], flow: str, key_exprs: Iterable[str]) -> dict:
    return {"id": rid, "messages": list(messages), "flows": [flow], "permission": "allow",
            "key_exprs": sorted(set(key_exprs))}


ALL_MESSAGES = ("put", "delete", "declare_subscriber", "query", "declare_queryable", "reply", "liveliness_token",
                "declare_liveliness_subscriber", "liveliness_query")
PEER_ROUTERS = "peer-routers"


def acl_config(table: Sequence[Grant], peer_routers: Sequence[str] = ()) -> dict:
    """Zenoh ``access_control`` (default deny) that allows exactly what ``table`` says.

    ``peer_routers`` (certificate CNs of the other routers of a deployment) may relay
    everything of the table's runs both ways: the router a client connects to enforces
    that client's grant, so a put from ``uav/1`` on host B was checked by B's router
    before A's router sees it arrive from ``router/b``."""
    rules, subjects, policies = [], [], []
    for g in table:
        sid = file_stem(g.identity)
        subjects.append({"id": sid, "cert_common_names": [g.identity]})
        mine = []

        def add(kind: str, messages: Sequence[str], flow: str, exprs: Sequence[str]) -> None:
            if exprs:
                rules.append(_rule(f"{sid}-{kind}", messages, flow, exprs))
                mine.append(f"{sid}-{kind}")

        add("put", ("put", "delete"), "ingress", g.put)
        # A declared publisher sends only while the router has told it of a matching subscriber, and
        # a subscription such as uav/*/action is no key of uav/1's: it learns of every one in its run.
        add("put-matching", ("declare_subscriber",), "egress", sorted({_run_of(e) for e in g.put}))
        add("subscribe", ("declare_subscriber",), "ingress", g.subscribe)
        add("receive", ("put", "delete"), "egress", g.subscribe)
        add("token", ("liveliness_token",), "ingress", g.tokens)
        add("watch", ("declare_liveliness_subscriber", "liveliness_query"), "ingress", g.watch)
        add("watch-receive", ("liveliness_token", "reply"), "egress", g.watch)
        add("serve", ("declare_queryable", "reply"), "ingress", g.serve)
        add("serve-query", ("query",), "egress", g.serve)
        add("ask", ("query",), "ingress", g.ask)
        add("ask-reply", ("reply", "declare_queryable"), "egress", g.ask)
        if mine:
            policies.append({"id": sid, "rules": mine, "subjects": [sid]})
    if peer_routers:
        spaces = sorted({_run_of(e) for g in table for e in (*g.put, *g.subscribe, *g.tokens, *g.watch, *g.serve,
                                                             *g.ask)})
        subjects.append({"id": PEER_ROUTERS, "cert_common_names": sorted(peer_routers)})
        rules.append({"id": f"{PEER_ROUTERS}-relay", "messages": list(ALL_MESSAGES), "flows": ["ingress", "egress"],
                      "permission": "allow", "key_exprs": spaces})
        policies.append({"id": PEER_ROUTERS, "rules": [f"{PEER_ROUTERS}-relay"], "subjects": [PEER_ROUTERS]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


def _run_of(key_expr: str) -> str:
    """``truav/<run>/**`` for a key expression of that run."""
    return "/".join(key_expr.split("/")[:2]) + "/**"


# --- explain ---------------------------------------------------------------------------------------
def _matches(key_expr: str, pattern: str) -> bool:
    """Whether Zenoh key expression ``pattern`` includes ``key_expr`` (``*`` one chunk, ``**`` any)."""
    import zenoh
    return zenoh.KeyExpr(pattern).includes(zenoh.KeyExpr(key_expr))


def explain(table: Sequence[Grant], identity: str | None = None, key: str | None = None,
            peer_routers: Sequence[str] = ()) -> list[str]:
    """Lines telling who may put / subscribe where (optionally one identity, or who may use ``key``)."""
    ids = [g.identity for g in table]
    if identity is not None and not any(fnmatch.fnmatchcase(i, identity) for i in ids):
        raise CredentialsError(f"--identity {identity!r} matches no identity; known: {', '.join(ids[:8])} ...")
    out = []
    for g in table:
        if identity is not None and not fnmatch.fnmatchcase(g.identity, identity):
            continue
        if key is not None:
            verbs = [verb for verb, exprs in (("put", g.put), ("subscribe", g.subscribe), ("declare token", g.tokens),
                                              ("watch", g.watch), ("serve queries", g.serve), ("query", g.ask))
                     if any(_matches(key, e) for e in exprs)]
            out.append(f"{g.identity:<11} {key}: " + (", ".join(f"may {v}" for v in verbs) if verbs else "DENIED"))
            continue
        out.append(f"{g.identity}  (certificate CN={g.identity!r})")
        for verb, exprs in (("put", g.put), ("subscribe", g.subscribe), ("token", g.tokens), ("watch", g.watch)):
            out.append(f"  {verb:<9} " + (", ".join(exprs) if exprs else "- (denied)"))
        for verb, exprs in (("serve", g.serve), ("query", g.ask)):
            if exprs:
                out.append(f"  {verb:<9} " + ", ".join(exprs))
    if peer_routers and identity is None:
        out.append(f"{', '.join(sorted(peer_routers))} (the other routers): relay everything of the run both ways; "
                   f"each router enforces the grants of the clients connected to it")
    out.append("anyone else (no certificate, another CA, an expired certificate): cannot connect; "
               "anything not listed: denied by the router (default_permission deny)")
    return out


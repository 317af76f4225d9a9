"""Fault plans: timed faults on a running swarm, like Jepsen's nemesis or
toxiproxy's toxics: the plan (Fault, FaultPlan), its file format and its checks.
The link filter that applies a plan to messages is truav.bus.fault_filter.

A plan is TOML, one `[[fault]]` table per fault, times in seconds from the
start of the run:

    [[fault]]
    kind = "loss"            # message loss on links
    start = 5.0
    duration = 10.0          # omit for "until the end"
    probability = 0.3        # or a Gilbert-Elliott burst model:
    # p_good_to_bad = 0.05, p_bad_to_good = 0.3, loss_good = 0.0, loss_bad = 0.9
    keys = "uav/*/beacon"    # key pattern under truav/<run>/ (default "**": everything)
    src = "uav/*"            # sender pattern (default "*")
    dst = "uav/*"            # receiver pattern (default "*")

    [[fault]]
    kind = "latency"          # extra one-way delay
    start = 0.0
    fixed_ms = 100.0
    jitter_ms = 20.0          # uniform in [0, jitter)
    keys = "uav/*/beacon"

    [[fault]]
    kind = "partition"        # groups of agents that cannot hear each other
    start = 20.0
    duration = 10.0
    groups = [[0, 1], [2, 3, 4]]

    [[fault]]
    kind = "obs_loss"         # world -> agent observations lost
    start = 0.0
    probability = 0.2
    uavs = [1, 2]             # default: all

    [[fault]]
    kind = "crash"            # SIGKILL an agent process
    start = 12.0
    uav = 3
    restart_after = 5.0       # omit: never restarted

    [[fault]]
    kind = "freeze"           # SIGSTOP, then SIGCONT (a pause)
    start = 30.0
    duration = 3.0
    uav = 4                   # or target = "controller" (scheme central), "world" or "recorder" (--record)

    [[fault]]
    kind = "crash"            # SIGKILL the router; restarted on its endpoint (clients reconnect)
    start = 40.0
    target = "router"         # or "controller" (scheme central)
    restart_after = 1.0       # required for the router: the swarm cannot run without it

    [[fault]]
    kind = "crash"            # `up --ray` only: kill every process on a Ray node (its Ray workers:
    start = 50.0              # its router and its agents); the supervisor places its agents again
    target = "node"           # on the nodes left, resuming from their checkpoints
    node = 2                  # its index in the placement `up --ray` prints (node 0, the world's
                              # and the recorder's, cannot be lost); no restart_after

Scheme central adds the controller's links: its uplink is `keys = "uav/*/state"`
(received by `dst = "controller"`), its downlink `keys = "controller/cmd/*"`;
a partition group may hold "controller" (`groups = [[0, 1], ["controller", 2, 3, 4]]`:
UAVs 0 and 1 lose the controller, both ways).

Patterns are checked on load (chunks of key characters and the globs * ** ?
[...], starting with a TRUAV key root or a *), and `truav-swarm` refuses a
plan naming a UAV the swarm does not have (`check_plan_for`).

Loss, latency, partitions and observation loss act in the transport's link
filter on the receiving side (truav.bus.fault_filter), identically in every process. Their random
draws are counter-based: a uniform for the n-th message on a (src, dst, key)
link is a hash of (plan seed, fault index, link, n), so a plan means the same
thing in every process and is deterministic under its seed. Crashes and
freezes are real signals, sent by the supervisor of `truav-swarm up`.
"""

from __future__ import annotations

import fnmatch
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from truav.errors import UserError
from truav.config import read_toml

LINK_KINDS = ("loss", "latency", "partition", "obs_loss")
PROCESS_KINDS = ("crash", "freeze")
FAULT_KINDS = LINK_KINDS + PROCESS_KINDS
FOREVER = math.inf

_ALLOWED = {
    "loss": {"probability", "p_good_to_bad", "p_bad_to_good", "loss_good", "loss_bad", "keys", "src", "dst"},
    "latency": {"fixed_ms", "jitter_ms", "keys", "src", "dst"},
    "partition": {"groups"},
    "obs_loss": {"probability", "uavs"},
    "crash": {"uav", "target", "restart_after", "node"},
    "freeze": {"uav", "target"},
}
_COMMON = {"kind", "start", "duration"}
CONTROLLER = "controller"
"""A process a crash or freeze may name by ``target`` (scheme central), and a partition's group member."""
ROUTER, WORLD, RECORDER = "router", "world", "recorder"
NODE = "node"
"""A crash's target under `truav-swarm up --ray`: every process of one Ray node (its ``node`` index)."""
TARGETS = {"crash": (CONTROLLER, ROUTER, NODE), "freeze": (CONTROLLER, WORLD, RECORDER)}
"""The processes a crash or freeze may name by ``target`` (agents are named by ``uav``)."""


class PlanError(UserError):
    """A mistake in a fault plan; the message names the fault and the key."""


@dataclass(frozen=True)
class Fault:
    """One timed fault. Times in seconds from the start of the run."""

    kind: str
    start: float
    duration: float = FOREVER
    params: dict[str, Any] = field(default_factory=dict)

    @property
    def end(self) -> float:
        return self.start + self.duration

    def active(self, t: float) -> bool:
        return self.start <= t < self.end

    def describe(self) -> str:
        p = ", ".join(f"{k}={v}" for k, v in self.params.items())
        until = "" if math.isinf(self.duration) else f" for {self.duration:g} s"
        return f"{self.kind} at {self.start:g} s{until}" + (f" ({p})" if p else "")


@dataclass(frozen=True)
class FaultPlan:
    faults: tuple[Fault, ...] = ()
    seed: int = 0

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form (sent on the bus for run-time plan changes)."""
        return {"seed": self.seed, "fault": [
            {"kind": f.kind, "start": f.start, **({} if math.isinf(f.duration) else {"duration": f.duration}),
             **f.params} for f in self.faults]}

    def to_toml(self, header: str = "") -> str:
        """The plan as a plan file (``load_plan`` of it gives this plan back); ``header``: comment lines."""
        lines = [f"# {line}".rstrip() for line in header.splitlines()]
        lines.append(f"seed = {self.seed}")
        for fault in self.to_dict()["fault"]:
            lines += ["", "[[fault]]"] + [f"{k} = {_toml_value(v)}" for k, v in fault.items()]
        return "\n".join(lines) + "\n"

    @property
    def link_faults(self) -> tuple[Fault, ...]:
        return tuple(f for f in self.faults if f.kind in LINK_KINDS)

    @property
    def process_faults(self) -> tuple[Fault, ...]:
        return tuple(f for f in self.faults if f.kind in PROCESS_KINDS)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)  # repr of a float reads back as the same float
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"no TOML form for {v!r}")


def _number(where: str, key: str, v: Any, lo: float = 0.0, hi: float = math.inf) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
        raise PlanError(f"{where}: {key} must be a number in [{lo:g}, {hi:g}], got {v!r}")
    return float(v)


def _uav(where: str, key: str, v: Any) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v < 1024:
        raise PlanError(f"{where}: {key} must be a UAV id in [0, 1024), got {v!r}")
    return v


def plan_from_dict(data: dict[str, Any]) -> FaultPlan:
    """Validate a parsed plan; PlanError names the offending fault and key."""
    unknown = set(data) - {"fault", "seed"}
    if unknown:
        raise PlanError(f"unknown top-level key '{sorted(unknown)[0]}' (expected [[fault]] tables and seed)")
    seed = data.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise PlanError(f"seed must be an integer, got {seed!r}")
    raw = data.get("fault", [])
    if not isinstance(raw, list):
        raise PlanError("'fault' must be an array of tables ([[fault]])")
    faults = []
    for n, item in enumerate(raw):
        where = f"fault #{n + 1}"
        if not isinstance(item, dict):
            raise PlanError(f"{where}: must be a table")
        kind = item.get("kind")
        if kind not in FAULT_KINDS:
            raise PlanError(f"{where}: kind must be one of {', '.join(FAULT_KINDS)}, got {kind!r}")
        where = f"fault #{n + 1} ({kind})"
        extra = set(item) - _COMMON - _ALLOWED[kind]
        if extra:
            raise PlanError(f"{where}: unknown key '{sorted(extra)[0]}'")
        start = _number(where, "start", item.get("start", 0.0))
        duration = _number(where, "duration", item["duration"], 1e-6) if "duration" in item else FOREVER
        params = {k: v for k, v in item.items() if k not in _COMMON}
        faults.append(Fault(kind, start, duration, _check_params(where, kind, params)))
    return FaultPlan(tuple(faults), seed)


_PATTERN_CHUNK = re.compile(r"(?:[A-Za-z0-9_*?-]|\[!?[A-Za-z0-9_-]+\])+")
"""One chunk of a key or sender pattern: key characters, the globs * ? and [...] classes."""
_PATTERN_ROOTS = {
    "keys": ("world", "uav", "metrics", "fault", "control", "alive", "controller"),  # after truav/<run>/ (keys)
    "src": ("world", "uav", "recorder", "fault", "replay", "supervisor", "status", "controller"),  # senders
    "dst": ("world", "uav", "recorder", "fault", "replay", "supervisor", "status", "controller"),
}


def _check_pattern(where: str, key: str, value: Any) -> str:
    """A key/sender glob that is well formed and can match something TRUAV sends (a typo in
    a pattern would otherwise silently match nothing)."""
    if not isinstance(value, str) or not value:
        raise PlanError(f"{where}: {key} must be a non-empty pattern string")
    chunks = value.split("/")
    if not all(_PATTERN_CHUNK.fullmatch(c) for c in chunks):
        raise PlanError(f"{where}: {key} {value!r} is not a valid pattern (chunks of [A-Za-z0-9_-] and the "
                        f"globs * ** ? [...], separated by single '/')")
    roots = _PATTERN_ROOTS[key]
    if "*" not in chunks[0] and not any(fnmatch.fnmatchcase(r, chunks[0]) for r in roots):
        raise PlanError(f"{where}: {key} {value!r} matches nothing TRUAV sends (it must start with one of "
                        f"{', '.join(roots)}, or a *)")
    return value


def _check_params(where: str, kind: str, p: dict[str, Any]) -> dict[str, Any]:
    for key in ("keys", "src", "dst"):
        if key in p:
            _check_pattern(where, key, p[key])
    if kind == "loss":
        ge = {"p_good_to_bad", "p_bad_to_good", "loss_good", "loss_bad"}
        if "probability" in p and ge & set(p):
            raise PlanError(f"{where}: give either probability or the Gilbert-Elliott parameters, not both")
        if not ("probability" in p or {"p_good_to_bad", "p_bad_to_good"} <= set(p)):
            raise PlanError(f"{where}: needs probability, or p_good_to_bad and p_bad_to_good")
        for key in {"probability"} | ge:
            if key in p:
                p[key] = _number(where, key, p[key], 0.0, 1.0)
        if ge & set(p):
            p.setdefault("loss_good", 0.0)
            p.setdefault("loss_bad", 1.0)
    elif kind == "latency":
        p["fixed_ms"] = _number(where, "fixed_ms", p.get("fixed_ms", 0.0), 0.0, 60_000.0)
        p["jitter_ms"] = _number(where, "jitter_ms", p.get("jitter_ms", 0.0), 0.0, 60_000.0)
    elif kind == "partition":
        groups = p.get("groups")
        if not isinstance(groups, list) or len(groups) < 2 or not all(isinstance(g, list) and g for g in groups):
            raise PlanError(f"{where}: groups must be a list of at least two non-empty lists of UAV ids")
        seen: set = set()
        for g in groups:
            for u in g:
                if u != CONTROLLER:
                    _uav(where, "groups", u)
                if u in seen:
                    raise PlanError(f"{where}: UAV {u} is in two groups")
                seen.add(u)
    elif kind == "obs_loss":
        p["probability"] = _number(where, "probability", p.get("probability"), 0.0, 1.0) \
            if "probability" in p else _missing(where, "probability")
        if "uavs" in p:
            if not isinstance(p["uavs"], list):
                raise PlanError(f"{where}: uavs must be a list of UAV ids")
            for u in p["uavs"]:
                _uav(where, "uavs", u)
    else:  # crash, freeze
        if "uav" not in p and "target" not in p:
            raise PlanError(f"{where}: missing uav (an agent's id) or target ({' or '.join(map(repr, TARGETS[kind]))})")
        if "uav" in p and "target" in p:
            raise PlanError(f"{where}: give uav (an agent's id) or target, not both")
        if "target" in p and p["target"] not in TARGETS[kind]:
            raise PlanError(f"{where}: target must be one of {', '.join(map(repr, TARGETS[kind]))}, "
                            f"got {p['target']!r}")
        if kind == "crash" and p.get("target") == ROUTER and "restart_after" not in p:
            raise PlanError(f"{where}: a crash of the router needs restart_after (the swarm cannot run without it)")
        if "node" in p and p.get("target") != NODE:
            raise PlanError(f"{where}: node: only with target = \"node\"")
        if p.get("target") == NODE:
            _node(where, p)
        if "uav" in p:
            _uav(where, "uav", p["uav"])
        if "restart_after" in p:
            p["restart_after"] = _number(where, "restart_after", p["restart_after"], 0.0)
    return p


def _node(where: str, p: dict[str, Any]) -> None:
    if "node" not in p:
        _missing(where, "node (a Ray node's index in the placement `up --ray` prints)")
    if isinstance(p["node"], bool) or not isinstance(p["node"], int) or not 0 <= p["node"] < 1024:
        raise PlanError(f"{where}: node must be a Ray node's index in [1, 1024), got {p['node']!r}")
    if p["node"] == 0:
        raise PlanError(f"{where}: node 0 holds the world and the recorder: the run cannot survive its loss "
                        f"(name another node)")
    if "restart_after" in p:
        raise PlanError(f"{where}: no restart_after for a node: the supervisor places its agents again on the "
                        f"nodes left")


def node_faults(plan: FaultPlan) -> list[tuple[int, int]]:
    """The plan's node kills (truav-swarm up --ray): (fault index, node index) each."""
    return [(n, f.params["node"]) for n, f in enumerate(plan.faults) if f.kind == "crash" and f.params.get("target") == NODE]


def _missing(where: str, key: str):
    raise PlanError(f"{where}: missing {key}")


def load_plan(path: str | Path) -> FaultPlan:
    """A plan file, validated; PlanError names the file, the fault and the key."""
    data = read_toml(path, "fault plan", PlanError)
    try:
        return plan_from_dict(data)
    except PlanError as exc:
        raise PlanError(f"fault plan {path}: {exc}") from None


_UAV_IN_PATTERN = re.compile(r"(?:^|/)uav/(\d+)(?:/|$)")


def plan_uavs(fault: Fault) -> list[int]:
    """The UAV ids a fault names explicitly (ids, groups, and uav/<i> in its patterns)."""
    p = fault.params
    ids = [p["uav"]] if "uav" in p else []
    ids += list(p.get("uavs", [])) + [u for g in p.get("groups", []) for u in g if u != CONTROLLER]
    for key in ("keys", "src", "dst"):
        ids += [int(m) for m in _UAV_IN_PATTERN.findall(p.get(key, ""))]
    return ids


def names_controller(fault: Fault) -> bool:
    """Whether a fault needs the central controller: it kills or freezes it, or partitions it off. (A link
    pattern naming its keys is allowed anywhere: one plan can then stress every scheme's links alike.)"""
    p = fault.params
    return p.get("target") == CONTROLLER or any(CONTROLLER in g for g in p.get("groups", []))


def check_plan_for(plan: FaultPlan, n_uavs: int, path: str | Path | None = None,
                   scheme: str | None = None) -> FaultPlan:
    """A plan that names only UAVs of a swarm of ``n_uavs`` (a fault on UAV 99 of 5 is a typo) and,
    unless ``scheme`` is "central" (or None: not known here), not the controller."""
    for n, f in enumerate(plan.faults):
        if scheme is not None and scheme != "central" and names_controller(f):
            where = f"fault plan {path}: " if path is not None else ""
            raise PlanError(f"{where}fault #{n + 1} ({f.kind}) names the controller, but --scheme {scheme} has none "
                            f"(only --scheme central)")
        bad = sorted({u for u in plan_uavs(f) if u >= n_uavs})
        if bad:
            where = f"fault plan {path}: " if path is not None else ""
            raise PlanError(f"{where}fault #{n + 1} ({f.kind}) names UAV {bad[0]}, but the swarm has "
                            f"{n_uavs} UAVs (ids 0-{n_uavs - 1})")
    return plan

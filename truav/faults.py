"""Fault plans: timed faults on a running swarm, like Jepsen's nemesis or
toxiproxy's toxics, and the link filter that applies them in every process.

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

Scheme central adds the controller's links: its uplink is `keys = "uav/*/state"`
(received by `dst = "controller"`), its downlink `keys = "controller/cmd/*"`;
a partition group may hold "controller" (`groups = [[0, 1], ["controller", 2, 3, 4]]`:
UAVs 0 and 1 lose the controller, both ways).

Patterns are checked on load (chunks of key characters and the globs * ** ?
[...], starting with a TRUAV key root or a *), and `truav-swarm` refuses a
plan naming a UAV the swarm does not have (`check_plan_for`).

Loss, latency, partitions and observation loss act in the transport's link
filter on the receiving side, identically in every process. Their random
draws are counter-based: a uniform for the n-th message on a (src, dst, key)
link is a hash of (plan seed, fault index, link, n), so a plan means the same
thing in every process and is deterministic under its seed. Crashes and
freezes are real signals, sent by the supervisor of `truav-swarm up`.
"""

from __future__ import annotations

import fnmatch
import hashlib
import math
import re
import struct
import threading
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
    "crash": {"uav", "target", "restart_after"},
    "freeze": {"uav", "target"},
}
_COMMON = {"kind", "start", "duration"}
CONTROLLER = "controller"
"""A process a crash or freeze may name by ``target`` (scheme central), and a partition's group member."""
ROUTER, WORLD, RECORDER = "router", "world", "recorder"
TARGETS = {"crash": (CONTROLLER, ROUTER), "freeze": (CONTROLLER, WORLD, RECORDER)}
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
        if "uav" in p:
            _uav(where, "uav", p["uav"])
        if "restart_after" in p:
            p["restart_after"] = _number(where, "restart_after", p["restart_after"], 0.0)
    return p


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


# -- the link filter -----------------------------------------------------------------
def uniform(seed: int, fault: int, link: str, n: int, salt: int = 0) -> float:
    """Counter-based uniform in [0, 1): the same inputs give the same number in any process."""
    h = hashlib.blake2b(f"{seed}|{fault}|{salt}|{link}|{n}".encode(), digest_size=8).digest()
    return (struct.unpack("<Q", h)[0] >> 11) / float(1 << 53)


def _uav_of(identity: str) -> int | None:
    if identity.startswith("uav/"):
        try:
            return int(identity.split("/", 2)[1])
        except ValueError:
            return None
    return None


MAX_LINK_STATES = 16_384
"""Per-link counters a PlanFilter keeps at most (a swarm of 20 agents uses a few hundred)."""


class PlanFilter:
    """A transport LinkFilter applying a plan's link faults on the receive side.

    `t0_ns` is the run's start (wall clock, ns): plan times are relative to it.
    The plan can be swapped at run time with `set_plan`."""

    def __init__(self, plan: FaultPlan, run: str, t0_ns: int | None = None):
        self._lock = threading.Lock()
        self.t0_ns: int | None = None
        self._prefix = f"truav/{run}/"
        self._counts: dict[tuple[int, str], int] = {}
        self._bad: dict[tuple[int, str], bool] = {}
        self.set_plan(plan, t0_ns)

    def set_plan(self, plan: FaultPlan, t0_ns: int | None = None) -> None:
        with self._lock:
            self.plan = plan
            # Lets the Bus skip the filter (and its per-message cost) while no link fault is planned.
            self.passes_everything = not any(f.kind in LINK_KINDS for f in plan.faults)
            if t0_ns is not None:
                self.t0_ns = t0_ns
            self._counts.clear()
            self._bad.clear()

    def start(self, t0_ns: int) -> None:
        """Set the run's time origin once (the world's first tick)."""
        with self._lock:
            if self.t0_ns is None:
                self.t0_ns = t0_ns

    def decide(self, key: str, src: str, dst: str, now_ns: int) -> tuple[bool, float]:
        if self.t0_ns is None:  # the run has not started: no faults yet
            return True, 0.0
        t = (now_ns - self.t0_ns) / 1e9
        rel = key[len(self._prefix):] if key.startswith(self._prefix) else key
        delay = 0.0
        with self._lock:
            for index, f in enumerate(self.plan.faults):
                if f.kind not in LINK_KINDS or not f.active(t):
                    continue
                if f.kind == "partition":
                    if self._partitioned(f, src, dst):
                        return False, 0.0
                    continue
                if f.kind == "obs_loss":
                    uav = _uav_of(dst)
                    if src != "world" or uav is None or not rel.endswith("/obs"):
                        continue
                    if f.params.get("uavs") and uav not in f.params["uavs"]:
                        continue
                    if self._draw(index, f"{src}>{dst}|{rel}") < f.params["probability"]:
                        return False, 0.0
                    continue
                p = f.params
                if not (fnmatch.fnmatchcase(rel, p.get("keys", "*").replace("**", "*"))
                        and fnmatch.fnmatchcase(src, p.get("src", "*"))
                        and fnmatch.fnmatchcase(dst, p.get("dst", "*"))):
                    continue
                link = f"{src}>{dst}|{rel}"
                if f.kind == "loss":
                    if self._lost(index, f, link):
                        return False, 0.0
                else:  # latency
                    jitter = p["jitter_ms"] * self._draw(index, link, salt=1) if p["jitter_ms"] else 0.0
                    delay += (p["fixed_ms"] + jitter) / 1e3
        return True, delay

    def _draw(self, index: int, link: str, salt: int = 0) -> float:
        n = self._counts.get((index * 2 + salt, link), 0)
        # Links are named by sender and key, which any sender chooses: past MAX_LINK_STATES links
        # new ones keep no state (each draw is its first), so a flood of names cannot grow memory.
        if n or len(self._counts) < MAX_LINK_STATES:
            self._counts[(index * 2 + salt, link)] = n + 1
        return uniform(self.plan.seed, index, link, n, salt)

    def _lost(self, index: int, f: Fault, link: str) -> bool:
        p = f.params
        if "probability" in p:
            return self._draw(index, link) < p["probability"]
        # Gilbert-Elliott: a two-state Markov chain per link, stepped per message.
        bad = self._bad.get((index, link), False)
        flip = p["p_bad_to_good"] if bad else p["p_good_to_bad"]
        if self._draw(index, link, salt=1) < flip:
            bad = not bad
        if (index, link) in self._bad or len(self._bad) < MAX_LINK_STATES:
            self._bad[(index, link)] = bad
        return self._draw(index, link) < (p["loss_bad"] if bad else p["loss_good"])

    @staticmethod
    def _partitioned(f: Fault, src: str, dst: str) -> bool:
        a = CONTROLLER if src == CONTROLLER else _uav_of(src)
        b = CONTROLLER if dst == CONTROLLER else _uav_of(dst)
        if a is None or b is None:
            return False
        groups = f.params["groups"]
        ga = next((i for i, g in enumerate(groups) if a in g), None)
        gb = next((i for i, g in enumerate(groups) if b in g), None)
        return ga is not None and gb is not None and ga != gb


CONTROL_FAULTS = "faults"
"""Control command carrying a new plan (args = FaultPlan.to_dict())."""


def attach_plan(bus, run: str, plan: FaultPlan | None, tick_period_s: float) -> PlanFilter:
    """Install a PlanFilter on a Bus. Time origin: the world's tick 0, inferred
    from the first tick heard (send time - tick x period, so a process
    restarted mid-run agrees). A `control/faults` message replaces the plan."""
    from truav.bus import keys

    flt = PlanFilter(plan or FaultPlan(), run)
    bus.link_filter = flt

    ticks = []  # the tick subscription, closed once the origin is known (junk on that key then costs nothing)

    def on_tick(key, msg, raw, recv_ns) -> None:
        if flt.t0_ns is None:
            flt.start(msg.t - int(msg.tick * tick_period_s * 1e9))
        if ticks:
            ticks.pop().close()

    def on_control(key, msg, raw, recv_ns) -> None:
        if msg.command == CONTROL_FAULTS:
            try:
                flt.set_plan(plan_from_dict(dict(msg.args)))
            except PlanError as exc:
                import logging
                logging.getLogger("truav.faults").warning("ignoring bad fault plan from %s: %s", msg.src, exc)

    ticks.append(bus.subscribe(keys.world_tick(run), on_tick))
    bus.subscribe(keys.control(run, CONTROL_FAULTS), on_control)
    return flt

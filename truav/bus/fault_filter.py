"""The link filter that applies a fault plan's link faults (loss, latency,
partition, observation loss) to received messages, identically in every
process, and its installation on a Bus (attach_plan).

Random draws are counter-based: a uniform for the n-th message on a (src,
dst, key) link is a hash of (plan seed, fault index, link, n), so a plan
means the same thing in every process and is deterministic under its seed.
The plan itself (its file format, its checks) is truav.faults.
"""

from __future__ import annotations

import fnmatch
import hashlib
import struct
import threading

from truav.faults import CONTROLLER, LINK_KINDS, Fault, FaultPlan, PlanError, plan_from_dict


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
    from truav.wire import keys

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


class SharedPlan:
    """What :func:`attach_plan` does, for the several agents one process hosts: each hosted Bus still
    gets its own PlanFilter (its own per-link counters and state bounds, so every fault applies per UAV
    link exactly as with one process per agent), but the process listens once, on one of its buses, for
    the world's first tick (the time origin) and for ``control/faults`` (a new plan), and hands both to
    every filter: two subscriptions (and their receive threads) per process instead of per agent."""

    def __init__(self, run: str, plan: FaultPlan | None, tick_period_s: float) -> None:
        self._run, self._period = run, tick_period_s
        self._plan = plan or FaultPlan()
        self._t0_ns: int | None = None
        self._lock = threading.Lock()
        self._filters: list[PlanFilter] = []
        self._ticks: list = []
        self._listening = False

    def attach(self, bus) -> PlanFilter:
        """A PlanFilter for ``bus`` (installed as its link filter), with the plan and origin known so far."""
        with self._lock:
            flt = PlanFilter(self._plan, self._run, self._t0_ns)
            self._filters.append(flt)
        bus.link_filter = flt
        return flt

    def listen(self, bus) -> None:
        """Subscribe (once per process: later calls do nothing) on ``bus`` to the tick and to control/faults."""
        from truav.wire import keys

        with self._lock:
            if self._listening:
                return
            self._listening = True
        self._ticks.append(bus.subscribe(keys.world_tick(self._run), self._on_tick))
        bus.subscribe(keys.control(self._run, CONTROL_FAULTS), self._on_control)

    def _on_tick(self, key, msg, raw, recv_ns) -> None:
        with self._lock:
            if self._t0_ns is None:
                self._t0_ns = msg.t - int(msg.tick * self._period * 1e9)
                for flt in self._filters:
                    flt.start(self._t0_ns)
            ticks, self._ticks = self._ticks, []
        for sub in ticks:
            sub.close()

    def _on_control(self, key, msg, raw, recv_ns) -> None:
        if msg.command != CONTROL_FAULTS:
            return
        try:
            plan = plan_from_dict(dict(msg.args))
        except PlanError as exc:
            import logging
            logging.getLogger("truav.faults").warning("ignoring bad fault plan from %s: %s", msg.src, exc)
            return
        with self._lock:
            self._plan = plan
            for flt in self._filters:
                flt.set_plan(plan)

"""The supervisor's fault controller: publishes every fault's start and end
on `truav/<run>/fault/<kind>` (so logs show them) and sends the real signals
for process faults: SIGKILL (+ restart from the checkpoint) for a crash,
SIGSTOP/SIGCONT for a freeze. Link faults need no action here: every
process applies them itself (truav.bus.fault_filter.PlanFilter).

A plan sent to the live run (`truav-swarm faults`, on control/faults) replaces the run's link faults in
every process; the controller hears it too, so its link faults are told, recorded and summed up as a
--fault-plan's are: a link fault of the old plan still active ends then, the old plan's pending link faults
are dropped, and the new plan's are scheduled (one already under way starts then; one already over never).
"""

from __future__ import annotations

import heapq
import logging
import math
import signal
import threading
import time
from typing import Callable

from truav.bus.fault_filter import CONTROL_FAULTS
from truav.bus.transport import Bus
from truav.faults import LINK_KINDS, NODE, Fault, FaultPlan, PlanError, plan_from_dict
from truav.wire import keys, schema

log = logging.getLogger("truav.faults")


def _target(f: Fault) -> str:
    if "target" in f.params:
        return f.params["target"]
    if "uav" in f.params:
        return keys.uav_identity(f.params["uav"])
    if f.kind == "partition":
        return " | ".join(",".join(map(str, g)) for g in f.params["groups"])
    if f.kind == "obs_loss":
        return ",".join(f"uav/{u}" for u in f.params.get("uavs", [])) or "all"
    return f"{f.params.get('src', '*')}>{f.params.get('dst', '*')} {f.params.get('keys', '**')}"


def _params(f: Fault) -> dict:
    return {k: v for k, v in f.params.items() if isinstance(v, (int, float, str)) and not isinstance(v, bool)}


class FaultController:
    """Runs a plan's schedule against the processes of one swarm, and the link faults of plans sent to it live.

    kill(who) / freeze(who) / thaw(who) / restart(who) are the supervisor's
    process hooks (they act only on processes the supervisor started); ``who``
    is a UAV id (its agent) or a process target such as "controller"."""

    def __init__(self, bus: Bus, run: str, plan: FaultPlan, hooks: dict[str, Callable[[int], None]]):
        self.bus, self.run, self.plan, self.hooks = bus, run, plan, hooks
        self.events: list[tuple[float, str, str]] = []  # (t, kind, phase) as executed
        self.plans_sent: list[dict] = []  # plans sent to the live run: {"t_s", "src", "link_faults", "plan"}
        self._stop = threading.Event()
        self._wake = threading.Event()  # set by stop() and by a plan sent live: the loop looks at once
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._t0: float | None = None
        self._seq = 0
        self._heap: list[tuple[float, int, str, Fault]] = []
        self._active: dict[int, Fault] = {}  # id() of a link fault started and not yet ended -> the fault
        for f in plan.faults:
            self._push_fault(f, 0.0)
        bus.subscribe(keys.control(run, CONTROL_FAULTS), self._on_plan)

    def start(self, t0_monotonic: float) -> None:
        self._t0 = t0_monotonic
        self._thread = threading.Thread(target=self._loop, args=(t0_monotonic,), name="faults", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=5)

    def _push(self, due: float, phase: str, f: Fault) -> None:
        heapq.heappush(self._heap, (due, self._seq, phase, f))
        self._seq += 1

    def _push_fault(self, f: Fault, now: float) -> None:
        """Schedule ``f``'s start and end (what is already past at ``now``, s after tick 0, comes at ``now``; a
        link fault over by then not at all)."""
        end = f.start + f.params["restart_after"] if f.kind == "crash" and "restart_after" in f.params else f.end
        if f.kind in LINK_KINDS and end <= now:
            return
        self._push(max(f.start, now), schema.PHASE_START, f)
        if f.kind != "crash" or "restart_after" in f.params:
            if math.isfinite(end):
                self._push(max(end, now), schema.PHASE_END, f)

    def _on_plan(self, key, msg, raw, recv_ns) -> None:
        """A plan sent to the live run: the processes replace their link faults with its; so does the schedule."""
        if msg.command != CONTROL_FAULTS:
            return
        try:
            plan = plan_from_dict(dict(msg.args))
        except PlanError as exc:  # the processes ignore it too (truav.bus.fault_filter)
            log.warning("ignoring bad fault plan from %s: %s", msg.src, exc)
            return
        with self._lock:
            now = 0.0 if self._t0 is None else max(0.0, time.monotonic() - self._t0)
            self._heap = [e for e in self._heap if e[3].kind not in LINK_KINDS]
            heapq.heapify(self._heap)
            for f in self._active.values():  # the old plan's link faults under way end now
                self._push(now, schema.PHASE_END, f)
            for f in plan.link_faults:
                self._push_fault(f, now)
            self.plans_sent.append({"t_s": round(now, 2), "src": msg.src, "link_faults": len(plan.link_faults),
                                    "plan": plan.to_dict()})
        self._wake.set()
        log.info("fault plan from %s at %.1f s: %d link fault(s) replace the run's", msg.src, now,
                 len(plan.link_faults))

    def _loop(self, t0: float) -> None:
        while not self._stop.is_set():
            with self._lock:
                due = self._heap[0] if self._heap else None
                wait = 0.1 if due is None else t0 + due[0] - time.monotonic()
                if due is not None and wait <= 0:
                    heapq.heappop(self._heap)
                    _, _, phase, f = due
                    if f.kind in LINK_KINDS:
                        if phase == schema.PHASE_START:
                            self._active[id(f)] = f
                        elif self._active.pop(id(f), None) is None:
                            continue  # ended already (its plan was replaced)
            if due is None or wait > 0:
                self._wake.wait(min(wait, 0.1))
                self._wake.clear()
                continue
            applied = time.monotonic() - t0  # when it was due and applied (a router's restart then takes a while)
            try:
                self._apply(f, phase)
            except Exception:  # a failed signal must not end the schedule
                log.exception("fault %s %s failed", f.describe(), phase)
            self.events.append((applied, f.kind, phase))

    def _apply(self, f: Fault, phase: str) -> None:
        uav = f.params.get("target", f.params.get("uav"))
        message = schema.Fault(fault=f.kind, phase=phase, target=_target(f), params=_params(f))
        if phase == schema.PHASE_START:  # before the signal: a router killed would take the message with it
            self.bus.publish(keys.fault(self.run, f.kind), message)
        if f.kind == "crash" and uav == NODE:  # `up --ray`: a whole node (no restart: its agents move)
            if phase == schema.PHASE_START:
                self.hooks["kill_node"](f.params["node"])
        elif f.kind == "crash":
            (self.hooks["kill"] if phase == schema.PHASE_START else self.hooks["restart"])(uav)
        elif f.kind == "freeze":
            (self.hooks["freeze"] if phase == schema.PHASE_START else self.hooks["thaw"])(uav)
        if phase != schema.PHASE_START:
            self.bus.publish(keys.fault(self.run, f.kind), message)
        log.info("fault %s: %s", phase, f.describe())


SIGNALS = {"kill": signal.SIGKILL, "freeze": signal.SIGSTOP, "thaw": signal.SIGCONT}

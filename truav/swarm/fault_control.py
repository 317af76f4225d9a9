"""The supervisor's fault controller: publishes every fault's start and end
on `truav/<run>/fault/<kind>` (so logs show them) and sends the real signals
for process faults: SIGKILL (+ restart from the checkpoint) for a crash,
SIGSTOP/SIGCONT for a freeze. Link faults need no action here: every
process applies them itself (truav.bus.fault_filter.PlanFilter).
"""

from __future__ import annotations

import heapq
import logging
import math
import signal
import threading
import time
from typing import Callable

from truav.bus.transport import Bus
from truav.faults import Fault, FaultPlan
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
    """Runs a plan's schedule against the processes of one swarm.

    kill(who) / freeze(who) / thaw(who) / restart(who) are the supervisor's
    process hooks (they act only on processes the supervisor started); ``who``
    is a UAV id (its agent) or a process target such as "controller"."""

    def __init__(self, bus: Bus, run: str, plan: FaultPlan, hooks: dict[str, Callable[[int], None]]):
        self.bus, self.run, self.plan, self.hooks = bus, run, plan, hooks
        self.events: list[tuple[float, str, str]] = []  # (t, kind, phase) as executed
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self, t0_monotonic: float) -> None:
        self._thread = threading.Thread(target=self._loop, args=(t0_monotonic,), name="faults", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)

    def _schedule(self) -> list[tuple[float, int, str, Fault]]:
        heap: list[tuple[float, int, str, Fault]] = []
        for n, f in enumerate(self.plan.faults):
            heap.append((f.start, n * 2, schema.PHASE_START, f))
            end = f.start + f.params["restart_after"] if f.kind == "crash" and "restart_after" in f.params else f.end
            if f.kind != "crash" or "restart_after" in f.params:
                if math.isfinite(end):
                    heap.append((end, n * 2 + 1, schema.PHASE_END, f))
        heapq.heapify(heap)
        return heap

    def _loop(self, t0: float) -> None:
        heap = self._schedule()
        while heap and not self._stop.is_set():
            due, _, phase, f = heap[0]
            wait = t0 + due - time.monotonic()
            if wait > 0:
                self._stop.wait(min(wait, 0.1))
                continue
            heapq.heappop(heap)
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
        if f.kind == "crash":
            (self.hooks["kill"] if phase == schema.PHASE_START else self.hooks["restart"])(uav)
        elif f.kind == "freeze":
            (self.hooks["freeze"] if phase == schema.PHASE_START else self.hooks["thaw"])(uav)
        if phase != schema.PHASE_START:
            self.bus.publish(keys.fault(self.run, f.kind), message)
        log.info("fault %s: %s", phase, f.describe())


SIGNALS = {"kill": signal.SIGKILL, "freeze": signal.SIGSTOP, "thaw": signal.SIGCONT}

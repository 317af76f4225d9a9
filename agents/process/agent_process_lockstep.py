"""What only a lock-step agent does: keep its peers' beacons per tick and wait for every live peer's.

A decision uses exactly its own tick's beacons, so a peer already on the next tick cannot change it.
A live peer heard since it joined is waited for up to ``lockstep_wait_s``; one not heard yet for
LOCKSTEP_JOIN_GRACE_S (per hundred UAVs of the swarm: :func:`join_grace_s`). A decision taken without a live process's message is counted (:class:`Inexact`):
the run is then no longer exactly reproducible.

:class:`LockstepBeacons` is a part of agents.process.agent_process.AgentNode (which also holds the real-time
half, agents.process.agent_process_realtime); it uses the node's lock, stop event, beacon inbox and peers gone.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from truav.wire import schema
from truav.wire.schema import LOCKSTEP_JOIN_GRACE_S

log = logging.getLogger("truav.agent")


JOIN_GRACE_UAVS = 100
"""A peer not heard since it joined is waited for LOCKSTEP_JOIN_GRACE_S per this many UAVs of the swarm (at least
LOCKSTEP_JOIN_GRACE_S): at the first tick no peer has been heard yet, and a round of a thousand UAVs on a few
cores takes seconds, so a fixed grace made every large run inexact from tick 0."""


def join_grace_s(n_uavs: int) -> float:
    """How long a lock-step agent waits for a live peer not heard since it joined, in a swarm of ``n_uavs``."""
    return LOCKSTEP_JOIN_GRACE_S * max(1.0, n_uavs / JOIN_GRACE_UAVS)


class Inexact:
    """Lock-step decisions taken without a live process's message (the wait ran out): how many, from which tick."""

    def __init__(self) -> None:
        self.decisions = 0
        self.from_tick: int | None = None

    def add(self, tick: int) -> None:
        self.decisions += 1
        self.from_tick = tick if self.from_tick is None else min(self.from_tick, tick)

    def as_dict(self) -> dict:
        return {"decisions_without_peer": self.decisions, "inexact_from_tick": self.from_tick}


class LockstepBeacons:
    """The lock-step half of an agent node: beacons per tick, the wait for a tick's, the inexact count."""

    def _init_lockstep(self) -> None:
        self._beacons_at: dict[int, dict[int, schema.Beacon]] = {}  # lock-step: tick -> {peer: its beacon}
        self._used_tick = -1  # lock-step: beacons of this tick or earlier come too late to be used
        self._heard: set[int] = set()  # lock-step: peers whose beacon came since they (last) joined
        self._peer_ids = frozenset(range(self.n_uavs)) - {self.opts.uav}
        self._join_grace_s = join_grace_s(self.n_uavs)
        self.inexact = Inexact()
        """Lock-step: the decisions taken without a live peer's (or, central, the controller's) message."""

    def _keep_lockstep_beacon(self, b: schema.Beacon) -> None:
        """A peer's beacon heard (under the node's lock): kept for its tick unless that tick is decided."""
        self._heard.add(b.uav)
        if b.tick > self._used_tick:
            self._beacons_at.setdefault(b.tick, {})[b.uav] = b

    def _take_lockstep_columns(self, parts: list) -> None:
        """The beacons a shared subscription decoded (agents.process.shared_beacons.Columns), into the tables as
        :meth:`_keep_lockstep_beacon` keeps them one by one (the last of a peer's for a tick wins), with
        their latency samples: a few numpy operations per chunk instead of Python per beacon."""
        me = self.opts.uav
        with self._lock:
            stopped = self._stopped_ns
            for c in parts:
                keep = c.uav != me
                counted = c.uav[keep & (c.uav < self.n_uavs)]
                if len(counted):
                    self.heard_from += np.bincount(counted, minlength=self.n_uavs)
                timed = keep if stopped is None else keep & (c.recv_ns <= stopped)
                if timed.any():
                    self._latency_ms.extend_array(c.latency_ms[timed])
                    self._latency_from.extend_array(np.stack([c.uav[timed], c.tick[timed]], axis=1))
                if self._gone:
                    keep &= ~np.isin(c.uav, np.fromiter(self._gone, np.int64, len(self._gone)))
                idx = np.flatnonzero(keep)
                if not len(idx):
                    continue
                ticks = c.tick[idx]
                if ticks.min() != ticks.max():  # beacons of several ticks (rare): one by one
                    for i in idx.tolist():
                        self._keep_lockstep_beacon(c.msgs[i])
                    continue
                uavs = c.uav[idx].tolist()
                self._heard.update(uavs)
                tick = int(ticks[0])
                if tick > self._used_tick:
                    msgs = c.msgs
                    self._beacons_at.setdefault(tick, {}).update(zip(uavs, [msgs[i] for i in idx.tolist()]))

    def _lockstep_peer_joined(self, uav: int) -> None:
        """Under the node's lock: a restarted peer is not waited for long before its first beacon."""
        self._heard.discard(uav)

    def _lockstep_peer_lost(self, uav: int) -> None:
        """Under the node's lock: a lost peer's beacons are not used."""
        for at_tick in self._beacons_at.values():
            at_tick.pop(uav, None)

    def _lockstep_beacons(self, tick: int) -> dict[int, schema.Beacon]:
        """The beacons of exactly ``tick`` of every peer not known gone (waited for); older ones are dropped.

        A live peer heard since it joined is waited for up to ``lockstep_wait_s`` (a paused process); one
        not heard yet (a slow starter, a restarted agent the world did not send this tick to) for
        LOCKSTEP_JOIN_GRACE_S. Deciding without a live peer's beacon is counted (:class:`Inexact`)."""
        start = time.monotonic()
        wait_s = self.opts.lockstep_wait_s
        while True:
            with self._lock:
                got = self._beacons_at.get(tick, {})
                # Every peer not known gone, so a slow starter is not skipped (set operations: 1,000 peers).
                missing = sorted(self._peer_ids.difference(self._gone, got))
                waited = time.monotonic() - start
                waiting = [j for j in missing if waited < (wait_s if j in self._heard else self._join_grace_s)]
            if not waiting or self._stop.is_set():
                break
            # Woken once enough beacons came for all the missing ones, not for each; a peer's loss shows within 50 ms.
            self._beacon_inbox.wait(0.05, min_ready=len(missing))
            self._take_beacons()
        if missing and not self._stop.is_set():  # the run is no longer exactly reproducible: say so
            self.inexact.add(tick)
            log.warning("uav %d, tick %d: no beacon from live peer(s) %s within %.1f s; deciding without them "
                        "(the run is no longer exact)", self.opts.uav, tick, missing, time.monotonic() - start)
        with self._lock:
            fresh = self._beacons_at.pop(tick, {})
            self._used_tick = max(self._used_tick, tick)
            for old in [t for t in self._beacons_at if t <= tick]:
                del self._beacons_at[old]
        return fresh

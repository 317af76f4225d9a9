"""What only a federated agent does (``federated.every`` > 0): share its Q rows and merge its peers'.

After the episodes of a share round (agents.federated.share_due), once it has learned from the episode's
last observation, the agent publishes its share (agents.federated.make_share) in parts of at most
schema.MAX_QSHARE_ROWS rows on ``uav/<i>/qshare/<n>`` and merges its peers' complete shares of the round
by agents.federated.merge, in UAV-id order, each checked first (agents.federated.check_share: a refused
share is counted by reason and changes nothing). Lock-step: it waits for every live peer's share of the
round (a peer heard since it joined up to ``lockstep_wait_s``, else LOCKSTEP_JOIN_GRACE_S, as for
beacons; deciding without one is counted in :class:`~agents.process.agent_process_lockstep.Inexact`), so the swarm
learns the in-process federated trainer's tables. Real time: it does not wait; a peer's share of its latest
round is merged at its next decision once every part has come, a share of an older round is stale.

Received parts are kept per (round, peer), bounded: only share rounds not older than this agent's last,
the MAX_ROUNDS_KEPT nearest (a round further ahead is refused, bad_round: it cannot push out the present
one), at most as many parts as a share of ``federated.max_rows`` rows has, each part of a peer's share once. Link faults (loss, latency, partition) reach
the shares as any message: the receive side's link filter applies to their keys.

:class:`FederatedShares` is a part of agents.process.agent_process.AgentNode; it uses the node's lock, stop event,
peers gone, learners and the lock-step part's ``_heard`` and ``inexact``.
"""

from __future__ import annotations

import logging
import threading
import time

import numpy as np

from agents.federated import (R_AHEAD, R_ROUND, R_SHAPE, Share, check_share, join_parts, make_share, max_count,
                              max_parts, merge, rounds_to_keep, share_due, split_share)
from truav.wire import keys, schema

log = logging.getLogger("truav.agent")

MAX_ROUNDS_KEPT = 4
"""Share rounds whose parts an agent keeps at once (a peer ahead by a round or two in real time)."""


class FederatedShares:
    """The federated half of an agent node: its visit counts, its shares out, its peers' in, the merges."""

    def _init_federated(self) -> None:
        self.fed = self.cfg.federated
        self.visits = np.zeros(self.encoder.n_states, np.int64)
        """This agent's updates per state (the weights of its rows in a merge)."""
        self.visits_at_share = np.zeros_like(self.visits)
        self._parts: dict[tuple[int, int], dict[int, schema.QShare]] = {}  # (round, peer) -> {part: message}
        self._round = -1  # the last round this agent shared in: older shares are stale
        self._max_parts = max_parts(self.fed, schema.MAX_QSHARE_ROWS)
        self._parts_cond = threading.Condition(self._lock)
        self.fed_stats = {"shares_sent": 0, "messages_sent": 0, "bytes_sent": 0, "rows_sent": 0,
                          "shares_merged": 0, "rows_changed": 0, "refused": {}, "missing": 0}

    def _setup_federated(self, bus) -> None:
        if self.fed.every > 0:
            bus.subscribe(keys.all_qshares(self.opts.run), self._on_qshare)

    def _count_visit(self, state: int) -> None:
        self.visits[state] += 1

    # -- delivery thread --
    def _on_qshare(self, key, msg: schema.QShare, raw, recv_ns) -> None:
        if msg.uav == self.opts.uav:
            return
        with self._parts_cond:
            if msg.episode < self._oldest_round() or msg.uav in self._gone:
                self._refuse(R_ROUND)
                return
            if msg.parts > self._max_parts:  # more parts than a share of federated.max_rows rows has
                self._refuse(R_SHAPE)
                return
            # Bounded: the nearest rounds only, so a peer far ahead (or claiming so) cannot grow this nor push
            # out the round this agent is about to merge.
            keep = rounds_to_keep({r for r, _ in self._parts} | {msg.episode}, self._oldest_round(), self.fed,
                                  MAX_ROUNDS_KEPT)
            if msg.episode not in keep:
                self._refuse(R_AHEAD)
                return
            for k in [k for k in self._parts if k[0] not in keep]:
                del self._parts[k]
            parts = self._parts.setdefault((msg.episode, msg.uav), {})
            parts.setdefault(msg.part, msg)  # a duplicate part changes nothing
            self._parts_cond.notify_all()

    def _oldest_round(self) -> int:
        """The oldest share round whose peers' shares are still wanted: this agent's last one, or (a resumed
        agent, which has not shared since) the last before its current episode."""
        decision = getattr(self, "decision", None)
        now = decision.episode if decision is not None else -1
        return max(self._round, now - self.fed.every)

    def _refuse(self, reason: str) -> None:
        refused = self.fed_stats["refused"]
        refused[reason] = refused.get(reason, 0) + 1

    # -- main loop --
    def _federated_round(self, episode: int, tick: int) -> None:
        """After learning from ``episode``'s last observation: share, then (lock-step) wait for and merge the
        peers' shares of the round."""
        if self.fed.every <= 0 or not self.opts.train or not share_due(episode, self.fed):
            return
        share = make_share(self.opts.uav, episode, self.learners.q[0, 0], self.visits, self.visits_at_share,
                           self.fed.max_rows)
        self.visits_at_share[...] = self.visits
        with self._lock:
            self._round = episode
            for k in [k for k in self._parts if k[0] < episode]:
                del self._parts[k]
        parts = split_share(share, schema.MAX_QSHARE_ROWS)
        for n, p in enumerate(parts):
            sent = self.bus.publish(keys.uav_qshare(self.opts.run, self.opts.uav, n), schema.QShare(
                uav=self.opts.uav, tick=tick, episode=episode, part=n, parts=len(parts), states=p.states,
                counts=p.counts, q=p.q.ravel()))
            self.fed_stats["messages_sent"] += 1
            self.fed_stats["bytes_sent"] += len(schema.encode(sent))
        self.fed_stats["shares_sent"] += 1
        self.fed_stats["rows_sent"] += len(share.states)
        if self.opts.lockstep:
            self._wait_for_shares(episode, tick)
            self._merge_ready()

    def _complete(self, episode: int) -> dict[int, list[schema.QShare]]:
        """Under the lock: the peers whose every part of round ``episode`` came, with their parts in order."""
        out = {}
        for (r, peer), parts in self._parts.items():
            if r == episode and parts and len(parts) == next(iter(parts.values())).parts \
                    and all(m.parts == len(parts) for m in parts.values()):
                out[peer] = [parts[n] for n in range(len(parts))]
        return out

    def _wait_for_shares(self, episode: int, tick: int) -> None:
        """Lock-step: wait for every live peer's complete share of round ``episode`` (bounded as for beacons)."""
        start, wait_s = time.monotonic(), self.opts.lockstep_wait_s
        with self._parts_cond:
            while True:
                done = self._complete(episode)
                missing = sorted(self._peer_ids.difference(self._gone, done))
                waited = time.monotonic() - start
                waiting = [j for j in missing if waited < (wait_s if j in self._heard else self._join_grace_s)]
                if not waiting or self._stop.is_set():
                    break
                self._parts_cond.wait(0.05)
        if missing and not self._stop.is_set():
            self.fed_stats["missing"] += len(missing)
            self.inexact.add(tick)
            log.warning("uav %d, episode %d: no Q share from live peer(s) %s within %.1f s; merging without them "
                        "(the run is no longer exact)", self.opts.uav, episode, missing, time.monotonic() - start)

    def _merge_ready(self) -> None:
        """Merge the peers' complete shares of this agent's last round, in UAV-id order, each checked first."""
        if self.fed.every <= 0 or self._round < 0:
            return
        episode = self._round
        with self._lock:
            done = self._complete(episode)
            for peer in done:
                del self._parts[(episode, peer)]
        if not done:
            return
        n_states, n_actions = self.learners.q.shape[2:]
        most = max_count(episode, self.cfg.scenario.steps_per_episode)
        accepted: list[Share] = []
        decision = getattr(self, "decision", None)
        for peer in sorted(done):
            if decision is not None and not decision.hear_share(peer, episode):
                continue  # channel-driven links: this share did not reach this UAV (the trainer loses it too)
            msgs = done[peer]
            try:
                share = join_parts([Share(peer, m.episode, m.states, m.counts, m.q.reshape(-1, n_actions))
                                    for m in msgs])
            except ValueError:  # a part whose values are not whole rows (the guard checks this too)
                self._refuse(R_SHAPE)
                continue
            why = check_share(share, n_states, n_actions, episode, most, self.fed.q_bound)
            if why is not None:
                self._refuse(why.split(":", 1)[0])
                log.warning("uav %d: refused the Q share of uav %d for episode %d: %s", self.opts.uav, peer,
                            episode, why)
                continue
            accepted.append(share)
        self.fed_stats["rows_changed"] += merge(self.learners.q[0, 0], self.visits, accepted, self.fed.max_weight)
        if decision is not None:  # rows a merge changed belong in a snapshot of the table too (agents.decision_state)
            decision.touched.update(int(s) for sh in accepted for s in sh.states)
        self.fed_stats["shares_merged"] += len(accepted)

    def federated_stats(self) -> dict:
        """For the stats file: what it shared (bytes and messages as put on the bus) and merged."""
        decision = getattr(self, "decision", None)
        lost = {} if decision is None else {str(j): c[1] for j, c in sorted(decision.share_counts.items())}
        return {**self.fed_stats, "every": self.fed.every, **({"channel_lost": lost} if lost else {})}

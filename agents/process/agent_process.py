"""One UAV's TRUAV agent as an OS process on the Zenoh bus.

It runs the trainer's own code (StateEncoder, Reward, QLearners with B=1,
U=1 and the same seed stream) and knows only what its UAV senses: its
observation from the world and the beacons it hears from its neighbours.
Per observation it publishes its beacon, builds its state from the beacons
of the same tick (lock-step: waits for every live peer's; real time: the
freshest heard), learns from the last step and publishes its action (in
lock-step a `done` observation is answered too, once learned from: the world
releases no later tick before that).

Lock-step beacons are kept per tick and a decision uses exactly its own
tick's, so a peer already on the next tick cannot change it.

Its Q-table can start from a trained run (`--qtable RUN_DIR`) and is
checkpointed atomically every K steps, at a step offset by UAV id so that a
swarm's agents do not all write (and fsync) in the same tick; a restarted
agent resumes from its checkpoint.

Threads: observations and control messages come through bus callbacks;
neighbour beacons collect in an :class:`~truav.bus.inbox.Inbox` that the main
loop drains once per decision (cheap arrival keeps the fan-out of 20+
agents' beacons off the CPU); in real time the main loop also sends this
agent's beacon in its slot of the tick while it waits for the next
observation (:mod:`agents.beacon_schedule`); a health thread reports.

:class:`AgentNode` is made of parts, one module each: what only lock-step
uses (agents.process.agent_process_lockstep), what only real time uses (agents.process.agent_process_realtime)
and its health report and stats file (agents.process.agent_process_reports); this module holds
the options, the bus wiring, the main loop and the decision.
"""

from __future__ import annotations

import gc
import json
import logging
import queue
import threading
import time
from pathlib import Path

import numpy as np

from agents.agent_decision import DONE_ACK_ACTION, TruavDecision, peer_arrays
from agents.decision_state import decision_state
from agents.prediction import new_maps, predict_batch, predict_params
from agents.process.agent_options import DELAY_ENV, AgentOptions, debug_delay_s  # noqa: F401 - their old home
from agents.process.agent_process_federated import FederatedShares
from agents.process.agent_process_lockstep import Inexact, LockstepBeacons
from agents.process.agent_process_realtime import REALTIME_BEACON_MAX_AGE_TICKS, RealtimeBeacons, realtime_inbox_capacity
from agents.process.agent_process_reports import AgentReports, HEALTH_PERIOD_S, MAX_INCARNATIONS_KEPT, SENT_KINDS
from agents.process.shared_beacons import SampleLog
from agents.qlearning import QLearners, geofence
from agents.reward import Reward
from agents.state import StateEncoder, neighbour_features
from truav import jsonio, seeding
from truav.analysis.runio import read_qtables
from truav.atomic import write_kept
from truav.bus import transport
from truav.bus.fault_filter import attach_plan
from truav.bus.transport import Bus
from truav.config import Config
from truav.faults import load_plan
from truav.lograte import Every
from truav.wire import guard, keys, schema
from truav.wire.snapshot_messages import agent_snapshot, fits, snapshot_due

log = logging.getLogger("truav.agent")

CONTROL_SHUTDOWN = "shutdown"

SENDER_JOIN_S = 2.0
"""At the end the agent waits this long for its beacon and health threads, so what it counts as sent is final."""


def checkpoint_due(steps: int, uav: int, n_uavs: int, every: int) -> bool:
    """Whether UAV ``uav`` checkpoints after ``steps`` steps: every ``every`` steps, at an offset
    by id so that a swarm's agents take turns (a write and fsync each) instead of all in one tick."""
    return (steps + uav * every // max(n_uavs, 1)) % every == 0


class AgentNode(LockstepBeacons, RealtimeBeacons, AgentReports, FederatedShares):
    """One agent: the bus wiring, the main loop and the TRUAV decision; the lock-step and real-time halves
    and the reports are its parts (agents.process.agent_process_lockstep, agents.process.agent_process_realtime,
    agents.process.agent_process_reports)."""

    def __init__(self, cfg: Config, opts: AgentOptions, bus: Bus, beacon_inbox=None, *, watch_peers: bool = True,
                 health_thread: bool = True, listen_shutdown: bool = True, shared_plan=None):
        """``beacon_inbox(bus)``, if given, returns this agent's beacon inbox (fed by a subscription its
        process shares among the agents it hosts); by default the agent subscribes on its own bus.

        A process hosting several agents shares what need not be per agent (agents.process.agent_host): with
        ``watch_peers`` False the node declares no liveliness watch (its host calls :meth:`_peer_joined` /
        :meth:`_peer_left` from one), with ``health_thread`` False run() starts no health thread (its host
        calls :meth:`publish_health`), with ``listen_shutdown`` False it does not subscribe to
        control/shutdown (its host calls :meth:`_on_control`), and with ``shared_plan`` (a
        truav.bus.fault_filter.SharedPlan) its bus's link filter is that plan's, whose listener is shared."""
        self.cfg, self.opts, self.bus = cfg, opts, bus
        self.encoder, self.reward = StateEncoder(cfg), Reward(cfg)
        self.predict = predict_params(cfg)
        self._density_map = new_maps(self.predict, 1, 1)
        """This UAV's decayed density map (agents/prediction.py), its decision's, in its checkpoint; no cells when off."""
        self.n_uavs = cfg.scenario.n_uavs
        self.steps = 0
        self.resumed = False  # started from its checkpoint: a restart within the same run
        self._last_tick = -1  # the tick of the last observation handled (health reports)
        self.out_of_order_obs = 0
        self.refused_by_world: dict[str, int] = {}
        """What the world told this agent it refused of its messages (rejections on uav/<i>/rejected), by reason."""
        """Observations dropped because their tick was not newer than one already answered (a delayed
        observation overtaken by a later one): learning from it would pair the wrong transition."""
        self.learners = self._make_learners()
        self.decision = TruavDecision(cfg, opts.uav, self.learners, opts.train, self.encoder, self.reward,
                                      self._density_map, seed=opts.seed)
        self._snapshot_too_large = False  # said once
        self._steps_at_start = self.steps
        self._earlier_incarnations = self._read_earlier_incarnations()
        self._debug = Every(log)
        self._obs: queue.Queue = queue.Queue()
        self._lock = threading.Lock()  # guards beacons, peers gone and latency samples
        self._gone: set[int] = set()  # peers whose liveliness token vanished
        self._latency_ms = SampleLog()  # a list of floats, kept in numpy chunks (1,000 agents hear 10^6 a tick)
        self._latency_from = SampleLog(width=2)  # (sender uav, tick) of each latency sample
        self.heard_from = np.zeros(self.n_uavs, np.int64)
        """Beacons this process heard from each peer (past its link filter), by sender id: the receiving end
        of each link, which the recorder (hearing every beacon) cannot see (health reports, stats file)."""
        self._stop = threading.Event()
        self._health_thread = health_thread
        self._health_lock = threading.Lock()  # a shared health thread's publish vs the end of run()
        self._health_done = False  # run() ended: no more health reports (its stats file counts what was sent)
        self.no_space: str | None = None  # a checkpoint or statistics write found the disk full: what it said
        self._stopped_ns: int | None = None  # beacons heard after this are not measured: no one waits for them
        self._episode = -1
        self._t = 0
        self._action = 0  # the last action (schemes without a TruavDecision)
        self._init_lockstep()
        self._init_realtime()
        self._init_federated()
        self._resume_visits()
        self._warm_up()
        run, me = opts.run, opts.uav
        bus.guard = guard.for_config(cfg)  # senders, value ranges, beacon ticks near the current one
        bus.accept_replay = opts.accept_replay
        # Real time: a full receive channel drops its oldest samples inside Zenoh and a full inbox its
        # oldest messages, so a flood costs this agent a bounded amount of work per tick (only the newest
        # observation and beacons matter); lock-step loses nothing and waits.
        bus.receive_ring = None if opts.lockstep else transport.REALTIME_RECEIVE_RING
        inbox_opts = {} if opts.lockstep else {"capacity": realtime_inbox_capacity(self.n_uavs), "compact": False}
        self.faults = shared_plan.attach(bus) if shared_plan is not None else \
            attach_plan(bus, run, load_plan(opts.fault_plan) if opts.fault_plan else None, opts.tick_period_s)
        bus.subscribe(keys.uav_obs(run, me), self._on_obs)
        # Rare (at most 10 a second): polled with the health report, no thread of its own.
        self.drain_rejections = bus.poll_subscribe(keys.uav_rejected(run, me), self._on_rejected)
        # Range-limited beacons: the inbox starts on the all-to-all key (no one sends there) and
        # follows this UAV's cells from its first observation on.
        self._beacon_inbox = bus.inbox(keys.all_beacons(run), **inbox_opts) if beacon_inbox is None \
            else beacon_inbox(bus, **inbox_opts)
        self._publish_beacon = bus.publish
        """Lock-step: how this agent's beacon goes out (its host may batch a process's: agents.process.shared_beacons)."""
        # Only the shutdown concerns an agent (its fault plan, if any, listens on its own key): junk on the
        # other control keys then never costs it anything.
        if listen_shutdown:
            bus.subscribe(keys.control(run, CONTROL_SHUTDOWN), self._on_control)
        if watch_peers:
            bus.watch_liveliness(keys.all_alive_uavs(run), self._on_join, self._on_leave)
        bus.prepare(*([keys.uav_beacon(run, me)] if self._cells is None else []), keys.uav_action(run, me),
                    keys.uav_health(run, me))
        self._setup_scheme(bus)
        self._setup_federated(bus)
        # Start-up objects (numpy, numba, zenoh) never become garbage: keep the cyclic collector off
        # them, or its occasional older-generation pass stalls this process 10-25 ms mid-run.
        gc.freeze()
        bus.declare_liveliness(keys.alive_uav(run, me))

    def _setup_scheme(self, bus: Bus) -> None:
        """Subscriptions and publishers another scheme's agent adds (agents.process.scheme_process), before it joins."""

    def scheme_stats(self) -> dict:
        """Statistics another scheme's agent adds to its stats file."""
        return {}

    def _warm_up(self) -> None:
        """Load the compiled kernels before joining, so the first tick is not missed."""
        pos = np.zeros((1, 1, 2))
        nearest, overlap = neighbour_features(pos, np.zeros((1, 1, 0, 2)), np.ones((1, 1, 0), np.bool_), 1.0)
        state = self.encoder.encode(pos, np.zeros((1, 1)), np.zeros((1, 1)), nearest,
                                    self.encoder.neighbour_sectors(pos, np.zeros((1, 1, 1, 2)), np.ones((1, 1, 1), np.bool_)),
                                    np.zeros((1, 1), np.int64),
                                    predict_batch(new_maps(self.predict, 1, 1), pos, np.zeros((1, 1)), self.predict))
        r = self.reward(np.zeros((1, 1)), np.zeros((1, 1)), np.zeros((1, 1)), overlap, np.zeros((1, 1)),
                        np.zeros((1, 1)), np.zeros((1, 1)))
        probe = QLearners(self.cfg.learner, 1, [np.random.default_rng(0)], 1, 1, q=np.zeros((1, 1, 1, 16)),
                          fence=geofence(self.cfg))
        probe.begin_episode(0, 1)
        probe.act(np.zeros((1, 1), np.int64), 0, pos)
        probe.update(np.zeros((1, 1), np.int64), np.zeros((1, 1), np.int64), r, np.zeros((1, 1), np.int64), False)
        del state

    def _resume_visits(self) -> None:
        """A resumed agent's visit counts (federated TRUAV's weights), from its checkpoint."""
        if self.resumed and self.opts.checkpoint:
            with np.load(self.opts.checkpoint) as ck:
                if "visits" in ck.files and ck["visits"].shape == self.visits.shape:
                    self.visits[...] = ck["visits"]
                    self.visits_at_share[...] = ck["visits_at_share"]

    def _make_learners(self) -> QLearners:
        o = self.opts
        rng = seeding.agent_rng(o.seed, o.uav)
        q = None
        if o.qtable:
            _, tables = read_qtables(o.qtable)
            q = tables[o.qtable_index, o.uav][None, None]
        learners = QLearners(self.cfg.learner, self.encoder.n_states, [rng], 1, 1, q=q, fence=geofence(self.cfg))
        if o.checkpoint and Path(o.checkpoint).is_file():
            with np.load(o.checkpoint) as ck:
                learners.q[0, 0] = ck["q"]
                self.steps = int(ck["steps"])
                rng.bit_generator.state = json.loads(str(ck["rng_state"]))
                if "density_map" in ck.files and ck["density_map"].shape == self._density_map.shape[2:]:
                    self._density_map[0, 0] = ck["density_map"]
            self.resumed = True
            log.info("uav %d resumed from checkpoint %s at step %d", o.uav, o.checkpoint, self.steps)
        else:
            log.info("uav %d starts from %s", o.uav, f"the tables of {o.qtable}" if o.qtable else "a fresh table")
        return learners

    # -- bus callbacks (delivery thread: keep short) --
    def _on_obs(self, key, msg: schema.Obs, raw, recv_ns) -> None:
        self._obs.put(msg)

    def _on_rejected(self, key, msg: schema.Rejection, raw, recv_ns) -> None:
        """The world refused messages of this agent: counted by reason, each reason's first logged."""
        new = [r for r in msg.counts if r not in self.refused_by_world]
        for reason, n in msg.counts.items():
            if reason in self.refused_by_world or len(self.refused_by_world) < schema.MAX_HEALTH_REASONS:
                self.refused_by_world[reason] = self.refused_by_world.get(reason, 0) + n
        if new:
            log.warning("uav %d: the world refused our %s on %s at tick %d: %s (%s); further '%s' refusals "
                        "only counted", self.opts.uav, msg.refused_kind or "message", msg.key, msg.at_tick,
                        msg.reason, msg.detail, "', '".join(new))

    def _on_control(self, key, msg: schema.Control, raw, recv_ns) -> None:
        if msg.command == CONTROL_SHUTDOWN:
            log.info("uav %d: shutdown from %s", self.opts.uav, msg.src)
            self.stop()

    def _on_join(self, key: str) -> None:
        uav = keys.parse_uav_id(key)
        if self._peer_joined(uav):
            log.info("uav %d: peer uav %d joined", self.opts.uav, uav)

    def _on_leave(self, key: str) -> None:
        uav = keys.parse_uav_id(key)
        if self._peer_left(uav):
            log.info("uav %d: peer uav %d lost", self.opts.uav, uav)

    def _peer_joined(self, uav: int | None) -> bool:
        """Peer ``uav``'s liveliness token appeared (False, nothing done: not a peer, or this UAV's own)."""
        if uav is None or uav == self.opts.uav:
            return False
        with self._lock:
            self._gone.discard(uav)
            self._lockstep_peer_joined(uav)  # a restarted peer: not waited for long before its first beacon
        return True

    def _peer_left(self, uav: int | None) -> bool:
        """Peer ``uav``'s liveliness token vanished (False, nothing done: not a peer, or this UAV's own)."""
        if uav is None or uav == self.opts.uav:
            return False
        with self._lock:
            self._gone.add(uav)
            self._realtime_peer_lost(uav)
            self._lockstep_peer_lost(uav)
        return True

    def stop(self) -> None:
        self._stopped_ns = time.time_ns()
        self._stop.set()
        self._obs.put(None)

    # -- main loop --
    def run(self) -> None:
        health = threading.Thread(target=self._health_loop, name="health", daemon=True) \
            if self._health_thread else None
        if health is not None:
            health.start()
        while not self._stop.is_set():
            if self.opts.lockstep:
                msg = self._obs.get()
            else:  # real time: the beacon goes out in its slot while this waits for the next observation
                try:
                    msg = self._obs.get(timeout=self._beacon_wait_s())
                except queue.Empty:
                    self._send_due_beacon()
                    continue
                if msg is not None:
                    msg = self._newest_obs(msg)
            if msg is None:
                break
            if msg.tick <= self._last_tick:  # overtaken: its transition is already past (and learned)
                self.out_of_order_obs += 1
                log.debug("uav %d: dropping observation of tick %d, not newer than tick %d already answered",
                          self.opts.uav, msg.tick, self._last_tick)
                continue
            self._last_tick = msg.tick
            self.handle(msg)
        if health is not None:
            health.join(SENDER_JOIN_S)  # it ends on the stop within ~50 ms: then the sent counts are final
        with self._health_lock:  # a shared health thread publishes no more for this node: the counts are final
            self._health_done = True
        self.checkpoint()

    def handle(self, obs: schema.Obs) -> None:
        """One observation: beacon, state, learn, act (the trainer's cycle for one agent: agents.agent_decision,
        which the re-simulation of a recording runs too)."""
        o, d = self.opts, self.decision
        if snapshot_due(o.lockstep, o.snapshot_every, obs.tick):
            self._publish_snapshot(obs.tick)
        self._send_beacon(obs)
        if o.debug_delay_s:
            self._stop.wait(o.debug_delay_s)
        peers, heard = self._peers(obs)
        s_prev = d.state  # the state the update below learns in: its visit is counted (federated TRUAV)
        r = d.learn(obs, peers, heard)
        if r is not None:
            if o.train:
                self._count_visit(s_prev)
            self.steps += 1
            if o.checkpoint and checkpoint_due(self.steps, o.uav, self.n_uavs, o.checkpoint_every):
                self.checkpoint()
        if obs.done:
            self._federated_round(obs.episode, obs.tick)  # once learned from the episode's last step
            if o.lockstep:  # the acknowledgement the world waits for before the next tick (and the shutdown)
                self.bus.publish(keys.uav_action(o.run, o.uav), d.acknowledge(obs))
            return
        if not o.lockstep:  # real time: peers' shares of the last round, merged as they complete
            self._merge_ready()
        self.bus.publish(keys.uav_action(o.run, o.uav), d.act(obs))
        if self._debug.due():
            log.debug("uav %d tick %d: received obs at (%.0f, %.0f) m, %d vehicles in range, %d packets queued, "
                      "beacons of %d peer(s) in range; decided state %d, reward %s, action %d (%s); sent it "
                      "(%d steps learned, %d stale observations skipped)", o.uav, obs.tick, *obs.pos,
                      obs.vehicles_in_range, obs.queued_packets, len(peers[0, 0]), d.state,
                      "-" if r is None else f"{float(r[0, 0]):.3f}", d.action,
                      "learning" if o.train else "greedy", self.steps, self.stale_obs_skipped)

    def _publish_snapshot(self, tick: int) -> None:
        """This agent's state before ``tick``'s observation, for `truav log resim --from`."""
        state = decision_state(self.decision)
        if not fits(state):
            if not self._snapshot_too_large:
                log.warning("uav %d: %d Q-table rows updated do not fit one snapshot message: not published",
                            self.opts.uav, len(state["q_rows"]))
            self._snapshot_too_large = True
            return
        self.bus.publish(keys.uav_snapshot(self.opts.run, self.opts.uav), agent_snapshot(self.opts.uav, tick, state))

    def _send_beacon(self, obs: schema.Obs) -> None:
        o = self.opts
        beacon = self.decision.beacon(obs)
        key = self._beacon_key(obs)
        if o.lockstep:  # every agent waits for it, the last observation's included
            self._publish_beacon(key, beacon)
            return
        self._schedule_beacon(obs, key, beacon)

    def _take_beacons(self) -> None:
        """Move the beacons heard since the last call from the inbox into the neighbour tables."""
        if self.opts.lockstep and hasattr(self._beacon_inbox, "drain_columns"):  # shared: in columns
            self._take_lockstep_columns(self._beacon_inbox.drain_columns())
            return
        heard = self._beacon_inbox.drain()
        with self._lock:
            for r in heard:
                b: schema.Beacon = r.msg
                if b.uav == self.opts.uav:
                    continue
                if b.uav < self.n_uavs:
                    self.heard_from[b.uav] += 1
                if self._stopped_ns is None or r.recv_ns <= self._stopped_ns:
                    self._latency_ms.append((r.recv_ns - b.t) / 1e6)
                    self._latency_from.append((b.uav, b.tick))
                if b.uav in self._gone:
                    continue
                if self.opts.lockstep:
                    self._keep_lockstep_beacon(b)
                else:
                    self._keep_freshest_beacon(b)

    def _peers(self, obs: schema.Obs) -> tuple[np.ndarray, np.ndarray]:
        """Neighbour positions from the beacons the channel delivers (all with ideal links), in UAV-id order
        (as the trainer sums them). Lock-step waits for every peer's beacon, then the channel decides which
        of them this UAV heard, as the trainer does: a lost beacon costs no wait."""
        self._take_beacons()
        tick = obs.tick
        fresh = self._lockstep_beacons(tick) if self.opts.lockstep else self._realtime_beacons_in_range(tick)
        return peer_arrays(self.decision.hear(obs, fresh))

    def checkpoint(self) -> None:
        """Atomically write the Q-table, step count and generator state."""
        if not self.opts.checkpoint:
            return
        path = Path(self.opts.checkpoint)
        state = jsonio.dumps(self.learners.rngs[0].bit_generator.state)
        if write_kept(path, lambda f: np.savez(f, q=self.learners.q[0, 0], steps=self.steps, rng_state=state,
                                               visits=self.visits, visits_at_share=self.visits_at_share,
                                               density_map=self.decision.density_map[0, 0]), self.say_no_space):
            log.info("uav %d: checkpoint at step %d -> %s", self.opts.uav, self.steps, path)

    def say_no_space(self, line: str) -> None:
        """A full disk: said once (it flies on, its last complete checkpoint kept), then the process exits
        EXIT_NO_SPACE (agents.process.agent_host)."""
        if self.no_space is None:
            log.error("uav %d: %s", self.opts.uav, line)
        self.no_space = line


__all__ = ["AgentNode", "AgentOptions", "CONTROL_SHUTDOWN", "DELAY_ENV", "DONE_ACK_ACTION", "HEALTH_PERIOD_S",
           "Inexact", "MAX_INCARNATIONS_KEPT", "REALTIME_BEACON_MAX_AGE_TICKS", "SENT_KINDS", "checkpoint_due",
           "debug_delay_s", "realtime_inbox_capacity"]

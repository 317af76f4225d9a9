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
agents' beacons off the CPU); in real time one thread sends this agent's
beacon in its slot of the tick (:mod:`agents.beacon_schedule`).
"""

from __future__ import annotations

import gc
import json
import logging
import os
import queue
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from agents.beacon_cells import BeaconCells, CellFollower, subscription_radius_m
from agents.beacon_schedule import BeaconSchedule, sends_beacon
from agents.qlearning import QLearners, geofence
from agents.reward import Reward
from agents.state import StateEncoder, neighbour_features
from truav import seeding
from truav.bus import guard, keys, schema, transport
from truav.config import Config
from truav.lograte import Every
from truav.options import opt
from truav.faults import attach_plan, load_plan
from truav.bus.transport import Bus
from truav.bus.schema import DEFAULT_LOCKSTEP_WAIT_S, LOCKSTEP_JOIN_GRACE_S
from world.uavs import action_velocity

log = logging.getLogger("truav.agent")

CONTROL_SHUTDOWN = "shutdown"
REALTIME_BEACON_MAX_AGE_TICKS = 10
"""Real time: a neighbour's beacon older than this many ticks (1 s at 10 Hz) is ignored."""
HEALTH_PERIOD_S = schema.HEALTH_PERIOD_S
"""How often an agent publishes its health report (what it refused, by reason and sender) on uav/<i>/health."""
DONE_ACK_ACTION = 0
"""The action field of a lock-step `done` observation's answer, an acknowledgement: the world ignores it."""
DELAY_ENV = "TRUAV_AGENT_DELAY_MS"
"""Testing only: ``UAV:MS[,UAV:MS...]`` makes those agents pause MS ms per observation (see debug_delay_s)."""


SENT_KINDS = (schema.KIND_BEACON, schema.KIND_ACTION, schema.KIND_STATE, schema.KIND_HEALTH)
"""What an agent counts as sent in its stats file (``sent``, per incarnation)."""
SENDER_JOIN_S = 2.0
"""At the end the agent waits this long for its beacon and health threads, so what it counts as sent is final."""
MAX_INCARNATIONS_KEPT = 1000
"""Earlier incarnations a restarted agent keeps listing in its stats file (bounded)."""


def debug_delay_s(spec: str, uav: int) -> float:
    """The pause of agent ``uav`` from a DELAY_ENV value ("" for none); ValueError if malformed."""
    for item in filter(None, (part.strip() for part in spec.split(","))):
        who, sep, ms = item.partition(":")
        try:
            who_id, delay_ms = int(who), float(ms)
        except ValueError:
            who_id, delay_ms = -1, -1.0
        if not sep or who_id < 0 or not 0 <= delay_ms < 60_000:
            raise ValueError(f"{DELAY_ENV}={spec!r}: expected UAV:MS[,UAV:MS...] with 0 <= MS < 60000")
        if who_id == uav:
            return delay_ms / 1e3
    return 0.0


def realtime_inbox_capacity(n_uavs: int) -> int:
    """Messages a real-time agent's inbox holds before evicting the oldest: a few ticks of every peer's
    beacons (it drains once a tick), so a flood costs at most this many decodes per tick."""
    return max(transport.REALTIME_RECEIVE_RING, 4 * n_uavs)


def checkpoint_due(steps: int, uav: int, n_uavs: int, every: int) -> bool:
    """Whether UAV ``uav`` checkpoints after ``steps`` steps: every ``every`` steps, at an offset
    by id so that a swarm's agents take turns (a write and fsync each) instead of all in one tick."""
    return (steps + uav * every // max(n_uavs, 1)) % every == 0


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


@dataclass
class AgentOptions:
    """How one agent process runs."""

    run: str = "demo"
    uav: int = 0
    seed: int = 0
    """Seed of the run: the agent draws from seeding.agent_rng(seed, uav)."""
    lockstep: bool = False
    lockstep_wait_s: float = DEFAULT_LOCKSTEP_WAIT_S
    """Lock-step: wait this long for a live peer's beacon (one heard since it joined; a peer not heard yet:
    LOCKSTEP_JOIN_GRACE_S) before deciding without it, which the stats count: the run is then not exact."""
    train: bool = True
    """Learn online (epsilon-greedy + updates); False acts greedily and never updates."""
    checkpoint: str | None = opt(None, flag="--checkpoint", metavar="FILE",
                                 help="Q-table checkpoint (.npz): resume from it, rewrite it")
    """Q-table checkpoint file (.npz): resumed from if it exists, rewritten every checkpoint_every steps."""
    checkpoint_every: int = opt(100, flag="--checkpoint-every", type="positive_int",
                                help="steps between checkpoints (default 100)")
    """K: UAV i checkpoints when (steps + i * K // n_uavs) % K == 0, so a swarm's writes are spread out."""
    qtable: str | None = opt(None, flag="--qtable", metavar="RUN", help="start from a trained run's Q-table")
    """Start from a trained run's qtables.npz (or run dir): the table of `qtable_index`, this UAV."""
    qtable_index: int = opt(0, flag="--qtable-index", type="non_negative_int",
                            help="which seed's table of that run (default 0)")
    beacon_phase: float = 0.3
    """Real time: beacons go out this fraction of the tick period after the
    tick starts, after the burst of observation deliveries and decisions..."""
    beacon_spread: float = 0.6
    """...spread over this fraction of the period by UAV id: synchronized sends
    from 20+ processes on a few cores multiply the latency tail (20 agents at
    10 Hz: one beacon every 3 ms, each reaching its 19 receivers in ~2 ms)."""
    tick_period_s: float = 0.1
    fault_plan: str | None = None
    """Fault plan (TOML) whose link faults apply to what this agent receives."""
    accept_replay: bool = False
    """Act on traffic a replay puts into this run (dropped and counted by default)."""
    stats_out: str | None = opt(None, flag="--stats-out", metavar="FILE",
                                help="write beacon latency statistics as JSON at exit")
    debug_delay_s: float = 0.0
    """Testing only: pause this long per observation between sending the beacon and reading the peers'
    (a deliberately slow agent: lock-step results must not change)."""
    scheme: str = "truav"
    """truav (this class) | patrol | central (agents.scheme_agents): what flies the UAV."""
    command_hold_s: float = opt(1.0, flag="--command-hold", type="non_negative_float", metavar="S",
                                help="--scheme central: without a fresh command a UAV keeps its last one this many "
                                     "seconds (world clock), then hovers (default 1)")
    """Scheme central: without a fresh command, keep flying the last one for this long (s of the
    world's clock, from the tick it was for), then hover: what an autopilot does when its link stops."""
    command_wait_frac: float = 0.5
    """Scheme central, real time: wait for the tick's command until this fraction of the tick period
    after the world stamped the observation (the world takes actions until deadline_frac, 0.8: the rest is for the action to get there on a busy host)."""
    beacon_every: int = opt(1, flag="--beacon-every", type="positive_int", metavar="TICKS",
                            help="real time: send a beacon every TICKS ticks, offset by id (10 at 10 Hz: 1 Hz, the "
                                 "Remote ID rate; default 1)")
    """Real time: send a beacon every this many ticks, offset by id (10 at 10 Hz: the Remote ID rate, 1 Hz)."""
    beacon_cell_m: float | None = opt(None, flag="--beacon-cell", type="positive_float", metavar="M",
                                      help="real time: range-limited beacons under map cells of M metres; hear only "
                                           "cells within range (agents/beacon_cells.py; default: all-to-all)")
    """Real time: range-limited beacons, under map cells of this side (agents.beacon_cells); None: all-to-all."""

    def __post_init__(self) -> None:
        if self.beacon_every < 1:
            raise ValueError(f"beacon_every must be >= 1, got {self.beacon_every}")
        if self.lockstep and (self.beacon_every != 1 or self.beacon_cell_m is not None):
            raise ValueError("lock-step waits for every live peer's beacon of each tick: "
                             "beacon_every and beacon_cell_m are for real time only")

    @property
    def beacon_max_age_ticks(self) -> int:
        """Real time: a neighbour's freshest beacon older than this is ignored (two intervals at a low rate)."""
        return max(REALTIME_BEACON_MAX_AGE_TICKS, 2 * self.beacon_every)


class AgentNode:
    def __init__(self, cfg: Config, opts: AgentOptions, bus: Bus, beacon_inbox=None):
        """``beacon_inbox(bus)``, if given, returns this agent's beacon inbox (fed by a subscription its
        process shares among the agents it hosts); by default the agent subscribes on its own bus."""
        self.cfg, self.opts, self.bus = cfg, opts, bus
        self.encoder, self.reward = StateEncoder(cfg), Reward(cfg)
        self.n_uavs = cfg.scenario.n_uavs
        self.steps = 0
        self.resumed = False  # started from its checkpoint: a restart within the same run
        self._last_tick = -1  # the tick of the last observation handled (health reports)
        self.stale_obs_skipped = 0
        """Real time: observations skipped because a newer one was already waiting (:meth:`_newest_obs`)."""
        self.out_of_order_obs = 0
        """Observations dropped because their tick was not newer than one already answered (a delayed
        observation overtaken by a later one): learning from it would pair the wrong transition."""
        self.learners = self._make_learners()
        self._steps_at_start = self.steps
        self._earlier_incarnations = self._read_earlier_incarnations()
        self._debug = Every(log)
        self._obs: queue.Queue = queue.Queue()
        self._lock = threading.Lock()  # guards beacons, peers gone and latency samples
        self._beacon_due = threading.Condition()  # wakes the real-time beacon thread, not every beacon heard
        self._beacons: dict[int, schema.Beacon] = {}  # real time: each peer's freshest beacon
        self._beacons_at: dict[int, dict[int, schema.Beacon]] = {}  # lock-step: tick -> {peer: its beacon}
        self._used_tick = -1  # lock-step: beacons of this tick or earlier come too late to be used
        self._gone: set[int] = set()  # peers whose liveliness token vanished
        self._heard: set[int] = set()  # lock-step: peers whose beacon came since they (last) joined
        self.inexact = Inexact()
        """Lock-step: the decisions taken without a live peer's (or, central, the controller's) message."""
        self._latency_ms: list[float] = []
        self._latency_from: list[tuple[int, int]] = []  # (sender uav, tick) of each latency sample
        self._stop = threading.Event()
        self._stopped_ns: int | None = None  # beacons heard after this are not measured: no one waits for them
        self._episode = -1
        self._t = 0
        self._state = 0
        self._action = 0
        self._velocity = (0.0, 0.0)
        self._pending_beacon = None
        self._schedule = BeaconSchedule(opts.tick_period_s, opts.beacon_phase, opts.beacon_spread, opts.uav,
                                        self.n_uavs)
        self._cells = None if opts.beacon_cell_m is None else BeaconCells(
            opts.beacon_cell_m, cfg.scenario.area_m, subscription_radius_m(cfg, opts.beacon_every,
                                                                           opts.beacon_max_age_ticks))
        if self._cells is not None and self._cells.radius_m == float("inf"):
            raise ValueError("beacon_cell_m: the state holds the nearest neighbour's direction at any distance "
                             "(learner.neighbour_sectors); range-limited beacons would change it")
        self._follower = None if self._cells is None else CellFollower(self._cells)
        self._cell_subs: dict = {}  # range-limited beacons: map cell -> its subscription handle
        self._own_pos = (0.0, 0.0)
        self._warm_up()
        run, me = opts.run, opts.uav
        bus.guard = guard.for_config(cfg)  # senders, value ranges, beacon ticks near the current one
        bus.accept_replay = opts.accept_replay
        # Real time: a full receive channel drops its oldest samples inside Zenoh and a full inbox its
        # oldest messages, so a flood costs this agent a bounded amount of work per tick (only the newest
        # observation and beacons matter); lock-step loses nothing and waits.
        bus.receive_ring = None if opts.lockstep else transport.REALTIME_RECEIVE_RING
        inbox_opts = {} if opts.lockstep else {"capacity": realtime_inbox_capacity(self.n_uavs), "compact": False}
        self.faults = attach_plan(bus, run, load_plan(opts.fault_plan) if opts.fault_plan else None,
                                  opts.tick_period_s)
        bus.subscribe(keys.uav_obs(run, me), self._on_obs)
        # Range-limited beacons: the inbox starts on the all-to-all key (no one sends there) and
        # follows this UAV's cells from its first observation on.
        self._beacon_inbox = bus.inbox(keys.all_beacons(run), **inbox_opts) if beacon_inbox is None \
            else beacon_inbox(bus, **inbox_opts)
        # Real time: the world's tick stamps anchor the beacon slot (agents.beacon_schedule).
        self._tick_inbox = None if opts.lockstep else bus.inbox(keys.world_tick(run), **inbox_opts)
        # Only the shutdown concerns an agent (its fault plan, if any, listens on its own key): junk on the
        # other control keys then never costs it anything.
        bus.subscribe(keys.control(run, CONTROL_SHUTDOWN), self._on_control)
        bus.watch_liveliness(keys.all_alive_uavs(run), self._on_join, self._on_leave)
        bus.prepare(*([keys.uav_beacon(run, me)] if self._cells is None else []), keys.uav_action(run, me),
                    keys.uav_health(run, me))
        self._setup_scheme(bus)
        # Start-up objects (numpy, numba, zenoh) never become garbage: keep the cyclic collector off
        # them, or its occasional older-generation pass stalls this process 10-25 ms mid-run.
        gc.freeze()
        bus.declare_liveliness(keys.alive_uav(run, me))

    def _setup_scheme(self, bus: Bus) -> None:
        """Subscriptions and publishers another scheme's agent adds (agents.scheme_agents), before it joins."""

    def scheme_stats(self) -> dict:
        """Statistics another scheme's agent adds to its stats file."""
        return {}

    def _warm_up(self) -> None:
        """Load the compiled kernels before joining, so the first tick is not missed."""
        pos = np.zeros((1, 1, 2))
        nearest, overlap = neighbour_features(pos, np.zeros((1, 1, 0, 2)), np.ones((1, 1, 0), np.bool_), 1.0)
        state = self.encoder.encode(pos, np.zeros((1, 1)), np.zeros((1, 1)), nearest,
                                    self.encoder.neighbour_sectors(pos, np.zeros((1, 1, 1, 2)), np.ones((1, 1, 1), np.bool_)),
                                    np.zeros((1, 1), np.int64))
        r = self.reward(np.zeros((1, 1)), np.zeros((1, 1)), np.zeros((1, 1)), overlap)
        probe = QLearners(self.cfg.learner, 1, [np.random.default_rng(0)], 1, 1, q=np.zeros((1, 1, 1, 16)),
                          fence=geofence(self.cfg))
        probe.begin_episode(0, 1)
        probe.act(np.zeros((1, 1), np.int64), 0, pos)
        probe.update(np.zeros((1, 1), np.int64), np.zeros((1, 1), np.int64), r, np.zeros((1, 1), np.int64), False)
        del state

    def _make_learners(self) -> QLearners:
        o = self.opts
        rng = seeding.agent_rng(o.seed, o.uav)
        q = None
        if o.qtable:
            from truav.runio import read_qtables
            _, tables = read_qtables(o.qtable)
            q = tables[o.qtable_index, o.uav][None, None]
        learners = QLearners(self.cfg.learner, self.encoder.n_states, [rng], 1, 1, q=q, fence=geofence(self.cfg))
        if o.checkpoint and Path(o.checkpoint).is_file():
            with np.load(o.checkpoint) as ck:
                learners.q[0, 0] = ck["q"]
                self.steps = int(ck["steps"])
                rng.bit_generator.state = json.loads(str(ck["rng_state"]))
            self.resumed = True
            log.info("uav %d resumed from checkpoint %s at step %d", o.uav, o.checkpoint, self.steps)
        else:
            log.info("uav %d starts from %s", o.uav, f"the tables of {o.qtable}" if o.qtable else "a fresh table")
        return learners

    # -- bus callbacks (delivery thread: keep short) --
    def _on_obs(self, key, msg: schema.Obs, raw, recv_ns) -> None:
        self._obs.put(msg)

    def _on_control(self, key, msg: schema.Control, raw, recv_ns) -> None:
        if msg.command == CONTROL_SHUTDOWN:
            log.info("uav %d: shutdown from %s", self.opts.uav, msg.src)
            self.stop()

    def _on_join(self, key: str) -> None:
        uav = keys.parse_uav_id(key)
        if uav is not None and uav != self.opts.uav:
            with self._lock:
                self._gone.discard(uav)
                self._heard.discard(uav)  # a restarted peer: not waited for long before its first beacon
            log.info("uav %d: peer uav %d joined", self.opts.uav, uav)

    def _on_leave(self, key: str) -> None:
        uav = keys.parse_uav_id(key)
        if uav is not None and uav != self.opts.uav:
            with self._lock:
                self._gone.add(uav)
                self._beacons.pop(uav, None)
                for at_tick in self._beacons_at.values():
                    at_tick.pop(uav, None)
            log.info("uav %d: peer uav %d lost", self.opts.uav, uav)

    def stop(self) -> None:
        self._stopped_ns = time.time_ns()
        self._stop.set()
        self._obs.put(None)
        with self._beacon_due:
            self._beacon_due.notify()

    # -- main loop --
    def run(self) -> None:
        senders = [threading.Thread(target=self._health_loop, name="health", daemon=True)]
        if not self.opts.lockstep:
            senders.append(threading.Thread(target=self._beacon_loop, name="beacons", daemon=True))
        for thread in senders:
            thread.start()
        while not self._stop.is_set():
            msg = self._obs.get()
            if msg is not None and not self.opts.lockstep:
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
        for thread in senders:  # both end on the stop within ~50 ms: then the sent counts are final
            thread.join(SENDER_JOIN_S)
        self.checkpoint()

    def health(self) -> schema.Health:
        """This agent's health report: what its bus refused, by reason and (the most refused) sender."""
        by_reason = sorted(self.bus.rejections.by_reason().items(), key=lambda kv: (-kv[1], kv[0]))
        by_sender: dict[str, int] = {}
        for per_sender in self.bus.rejections.as_dict().values():
            for sender, n in per_sender.items():  # a name a flood chose: shown in printable ASCII only
                shown = "".join(c if " " <= c <= "~" else "?" for c in sender)[:schema.MAX_SRC_LEN] or "?"
                by_sender[shown] = by_sender.get(shown, 0) + n
        top = sorted(by_sender.items(), key=lambda kv: (-kv[1], kv[0]))[:schema.MAX_HEALTH_SENDERS]
        return schema.Health(uav=self.opts.uav, last_tick=self._last_tick, steps=self.steps,
                             stale_obs_skipped=self.stale_obs_skipped,
                             rejected=dict(by_reason[:schema.MAX_HEALTH_REASONS]), senders=dict(top))

    def _health_loop(self) -> None:
        """About once a second (and at once, so `truav-swarm status` sees a fresh agent): the health report."""
        while True:
            try:
                self.bus.publish(keys.uav_health(self.opts.run, self.opts.uav), self.health())
            except RuntimeError:  # bus closed at shutdown
                return
            if self._stop.wait(HEALTH_PERIOD_S):
                return

    def _newest_obs(self, msg: schema.Obs) -> schema.Obs | None:
        """Real time: the world applies only the current tick's action, so an agent that fell behind
        (a slow spell, a flood) answers the newest observation and skips the older ones, counted,
        instead of answering each after its deadline and staying behind. None: stop."""
        while True:
            try:
                nxt = self._obs.get_nowait()
            except queue.Empty:
                return msg
            if nxt is None:
                return None
            # The newest tick is answered, whatever the arrival order (a delayed one can come after it).
            older, msg = (nxt, msg) if nxt.tick < msg.tick else (msg, nxt)
            if self.stale_obs_skipped == 0:
                log.info("uav %d: behind the world, answering tick %d and skipping tick %d (stale observations "
                         "are skipped from now on, counted in the stats)", self.opts.uav, msg.tick, older.tick)
            self.stale_obs_skipped += 1

    def handle(self, obs: schema.Obs) -> None:
        """One observation: beacon, state, learn, act (the trainer's cycle for one agent)."""
        o, T = self.opts, self.cfg.scenario.steps_per_episode
        self._send_beacon(obs)
        if o.debug_delay_s:
            self._stop.wait(o.debug_delay_s)
        peers, heard = self._peers(obs.tick)
        pos = np.array([[obs.pos]], dtype=np.float64)
        nearest, overlap = neighbour_features(pos, peers, heard, self.cfg.scenario.comm_range_m)
        state = self.encoder.encode(pos, np.array([[obs.vehicles_in_range]]), np.array([[obs.queued_packets]]),
                                    nearest, self.encoder.neighbour_sectors(pos, peers, heard),
                                    np.array([[obs.densest_sector]]))
        r = None
        if obs.episode != self._episode:
            self._episode, self._t = obs.episode, 0
            self.learners.begin_episode(obs.episode, T, greedy=not o.train)
        else:
            r = self.reward(np.array([[obs.relayed]]), np.array([[obs.covered]]),
                            np.array([[obs.energy_j]]), overlap)
            if o.train:
                self.learners.update(np.array([[self._state]]), np.array([[self._action]]), r, state, False)
            self._t += 1
            self.steps += 1
            if o.checkpoint and checkpoint_due(self.steps, o.uav, self.n_uavs, o.checkpoint_every):
                self.checkpoint()
        self._state = int(state[0, 0])
        if obs.done:
            if o.lockstep:  # the acknowledgement the world waits for before the next tick (and the shutdown)
                self.bus.publish(keys.uav_action(o.run, o.uav), schema.Action(uav=o.uav, tick=obs.tick,
                                                                             action=DONE_ACK_ACTION))
            return
        self._action = int(self.learners.act(state, min(self._t, T - 1), pos)[0, 0])
        self._velocity = tuple(action_velocity(np.array(self._action), obs.speed_max))
        self.bus.publish(keys.uav_action(o.run, o.uav), schema.Action(uav=o.uav, tick=obs.tick, action=self._action))
        if self._debug.due():
            log.debug("uav %d tick %d: received obs at (%.0f, %.0f) m, %d vehicles in range, %d packets queued, "
                      "beacons of %d peer(s) in range; decided state %d, reward %s, action %d (%s); sent it "
                      "(%d steps learned, %d stale observations skipped)", o.uav, obs.tick, *obs.pos,
                      obs.vehicles_in_range, obs.queued_packets, len(peers[0, 0]), self._state,
                      "-" if r is None else f"{float(r[0, 0]):.3f}", self._action,
                      "learning" if o.train else "greedy", self.steps, self.stale_obs_skipped)

    def _follow_cells(self, pos: tuple[float, float]) -> None:
        """Range-limited beacons: subscribe to the cells now within range of ``pos``, drop the others."""
        self._own_pos = pos
        add, drop = self._follower.move(*pos)
        for cell in drop:
            self._cell_subs.pop(cell).close()
        for cell in add:
            self._cell_subs[cell] = self.bus.feed(self._beacon_inbox, keys.beacons_in_cell(self.opts.run, cell))

    def _send_beacon(self, obs: schema.Obs) -> None:
        o = self.opts
        beacon = schema.Beacon(uav=o.uav, tick=obs.tick, pos=obs.pos, vel=self._velocity)
        key = keys.uav_beacon(o.run, o.uav)
        if self._cells is not None:
            self._follow_cells(obs.pos)
            key = keys.uav_beacon_in_cell(o.run, o.uav, self._cells.cell_of(*obs.pos))
        if o.lockstep:  # every agent waits for it, the last observation's included
            self.bus.publish(key, beacon)
            return
        for r in self._tick_inbox.drain():
            self._schedule.observe(r.msg.tick, r.msg.t / 1e9)
        self._schedule.observe(obs.tick, obs.t / 1e9)  # later than its tick's start: never lowers the estimate wrongly
        if obs.done or not sends_beacon(obs.tick, o.uav, o.beacon_every):  # done: no one acts on this tick
            return
        due = time.monotonic() + self._schedule.due(obs.tick) - time.time()  # world clock -> this host's monotonic
        with self._beacon_due:
            self._pending_beacon = (due, key, beacon)
            self._beacon_due.notify()

    def _beacon_loop(self) -> None:
        """Real time: one thread sends the latest pending beacon at its due time."""
        while not self._stop.is_set():
            with self._beacon_due:
                pending = self._pending_beacon
                if pending is None or pending[0] > time.monotonic():
                    wait = 0.05 if pending is None else min(pending[0] - time.monotonic(), 0.05)
                    self._beacon_due.wait(max(wait, 0.0))
                    continue
                self._pending_beacon = None
            try:
                self.bus.publish(pending[1], pending[2])
            except RuntimeError:  # bus closed at shutdown
                return

    def _take_beacons(self) -> None:
        """Move the beacons heard since the last call from the inbox into the neighbour tables."""
        heard = self._beacon_inbox.drain()
        with self._lock:
            for r in heard:
                b: schema.Beacon = r.msg
                if b.uav == self.opts.uav:
                    continue
                if self._stopped_ns is None or r.recv_ns <= self._stopped_ns:
                    self._latency_ms.append((r.recv_ns - b.t) / 1e6)
                    self._latency_from.append((b.uav, b.tick))
                if b.uav in self._gone:
                    continue
                if self.opts.lockstep:
                    self._heard.add(b.uav)
                    if b.tick > self._used_tick:
                        self._beacons_at.setdefault(b.tick, {})[b.uav] = b
                    continue
                prev = self._beacons.get(b.uav)
                if prev is None or b.tick >= prev.tick:
                    self._beacons[b.uav] = b

    def _peers(self, tick: int) -> tuple[np.ndarray, np.ndarray]:
        """Neighbour positions from beacons, in UAV-id order (as the trainer sums them)."""
        self._take_beacons()
        if self.opts.lockstep:
            fresh = self._lockstep_beacons(tick)
        else:
            oldest = tick - self.opts.beacon_max_age_ticks
            with self._lock:
                fresh = {j: b for j, b in self._beacons.items() if b.tick >= oldest}
            if self._cells is not None:  # beyond the radius a beacon cannot change the state (agents.beacon_cells)
                fresh = {j: b for j, b in fresh.items() if self._cells.in_range(self._own_pos, b.pos)}
        ids = sorted(fresh)
        peers = np.array([[[fresh[j].pos for j in ids]]], dtype=np.float64).reshape(1, 1, len(ids), 2)
        return peers, np.ones((1, 1, len(ids)), dtype=np.bool_)

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
                # Every peer not known gone, so a slow starter is not skipped.
                missing = [j for j in range(self.n_uavs) if j != self.opts.uav and j not in self._gone and j not in got]
                waited = time.monotonic() - start
                waiting = [j for j in missing if waited < (wait_s if j in self._heard else LOCKSTEP_JOIN_GRACE_S)]
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

    def checkpoint(self) -> None:
        """Atomically write the Q-table, step count and generator state."""
        if not self.opts.checkpoint:
            return
        path = Path(self.opts.checkpoint)
        tmp = path.with_name(path.name + ".tmp.npz")
        state = json.dumps(self.learners.rngs[0].bit_generator.state)
        np.savez(tmp, q=self.learners.q[0, 0], steps=self.steps, rng_state=state)
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
        log.info("uav %d: checkpoint at step %d -> %s", self.opts.uav, self.steps, path)

    def latency_stats(self) -> dict[str, float]:
        with self._lock:
            lat = np.array(self._latency_ms)
        if lat.size == 0:
            return {"n": 0}
        return {"n": int(lat.size), "p50": float(np.percentile(lat, 50)), "p99": float(np.percentile(lat, 99)),
                "max": float(lat.max())}

    def _read_earlier_incarnations(self) -> list[dict]:
        """A restarted agent (resumed from its checkpoint) keeps the ``incarnations`` of the stats file its
        earlier processes of this run wrote; a SIGKILLed one wrote none, so it is not listed."""
        path = self.opts.stats_out
        if not (self.resumed and path and Path(path).is_file()):
            return []
        try:
            old = json.loads(Path(path).read_text())
        except (OSError, ValueError):
            return []
        earlier = old.get("incarnations") if isinstance(old, dict) and old.get("run") == self.opts.run else None
        return [e for e in earlier if isinstance(e, dict)][-MAX_INCARNATIONS_KEPT:] if isinstance(earlier, list) else []

    def sent(self) -> dict[str, int]:
        """What this process published, by kind: beacons, actions, state uploads (central), health reports."""
        sent = self.bus.stats().sent
        return {kind: sent.get(kind, 0) for kind in SENT_KINDS}

    def write_stats(self) -> None:
        if self.opts.stats_out:
            self._take_beacons()  # the last tick's beacons count too
            with self._lock:
                samples = [round(x, 3) for x in self._latency_ms]
                senders = list(self._latency_from)
            st = self.bus.stats()
            data = {"uav": self.opts.uav, "steps": self.steps, "stale_obs_skipped": self.stale_obs_skipped,
                    "out_of_order_obs": self.out_of_order_obs,
                    **({"lockstep": self.inexact.as_dict()} if self.opts.lockstep else {}),
                    "beacon_latency_ms": self.latency_stats(),
                    "beacon_latency_samples_ms": samples, "beacon_latency_from": senders,
                    "bus": {"received": st.received, "filtered": st.filtered, "delayed": st.delayed,
                            "malformed": self.bus.dropped_malformed, "rejected": st.rejected},
                    "scheme": self.opts.scheme, **self.scheme_stats()}
            # what this process sent, to compare with a recording's (uav/<i>, kind, incarnation) streams
            me = {"inc": f"{self.bus.incarnation:016x}", "steps_from": self._steps_at_start, "steps_to": self.steps,
                  "sent": self.sent()}
            data.update(run=self.opts.run, incarnation=me["inc"], sent=me["sent"],
                        incarnations=[*self._earlier_incarnations, me])
            p = Path(self.opts.stats_out)
            tmp = p.with_name(p.name + ".tmp")
            tmp.write_text(json.dumps(data))
            tmp.replace(p)

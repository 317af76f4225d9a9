"""The world process: the same `World` as the trainer, behind Zenoh.

Per tick it publishes the tick and every UAV's local observation, collects
actions until all live agents answered (lock-step) or a deadline passed
(real time), applies them (a missing action hovers), steps, and publishes
step metrics; at an episode's end it publishes the `done` observation, the
episode metrics and starts the next one. In lock-step no tick is released
before every live agent has answered the previous one, the `done` observation
included (its answer only acknowledges: the agent has learned from it), so an
agent never sees a peer's beacon of a later tick before it is done with its
own. It watches the agents' liveliness tokens and logs joins and losses. Run
it alone with `truav-swarm world`, or let `truav-swarm up` start it.

What it counts and writes at exit (WorldStats, the action digest, the stats
file) is world.world_stats.
"""

from __future__ import annotations

import functools
import gc
import logging
import threading
import time

import numpy as np

from agents.central import ControlCounters
from truav import seeding
from truav.analysis.sumo_traffic import make_world
from truav.bus import transport
from truav.bus.fault_filter import attach_plan
from truav.bus.placement import facts_of
from truav.bus.rejections import rejection_metrics
from truav.bus.transport import Bus
from truav.config import Config
from truav.faults import load_plan
from truav.lograte import Every
from truav.stats import shown
from truav.wire import guard, keys, schema
from truav.wire.rejection_notices import RejectionNotices
from truav.wire.snapshot_messages import fits, snapshot_due, world_snapshot
from truav.wire.world_messages import observation_messages
from world.env import World
from world.process.world_options import WorldOptions
from world.uavs import HOVER
from world.steer import apply_overrides
from world.world_state import world_state
from world.world_stats import UavAccounts, WorldStats, action_digest, write_stats

log = logging.getLogger("truav.world")

MISS_LOG_PERIOD_S = 10.0
"""A UAV's first missed tick is logged at once (naming it); after that at most one line this often sums up
the UAVs that missed since the last one (100 missing UAVs at 10 Hz do not flood the log)."""
MISS_LOG_MAX_NAMED = 10
"""A missed-actions line names at most this many UAVs (the worst), and says how many more."""

STALL_MIN_S = 1.0
"""Real time: a tick starting this late (the world was paused, or the host stalled) is a stall, named in the
statistics and the summary. Any start a whole period late resumes from the current time (the missed ticks
are skipped, not published in a burst); shorter lateness is caught up."""
REJOIN_S = 1.0
"""An agent's token back within this long of vanishing was a connection that flapped (the world's own, after a
stall, drops every token at once), not an agent that left: a restarted agent takes seconds to start."""

CONTROL_SHUTDOWN = "shutdown"
POSITIONS_EVERY_TICKS = 1
"""Publish all positions (maps, replay, the Foxglove scene) every this many ticks: every tick,
so vehicles move smoothly in the viewer."""
POSITIONS_GRID_M = 1.0
"""Vehicle positions are published rounded to this grid (metres): far below what a map
or the Foxglove scene shows (a vehicle is drawn 40 m wide), and whole numbers
compress several times better in a recording than full float64 noise."""


def warm_up_kernels(cfg: Config, central: bool = False) -> None:
    """Compile (or load from the cache) every kernel a world step runs (and, under the central scheme,
    the control-plane model's), on a throwaway two-step world, before joining: on a cold cache that
    takes seconds, which would otherwise land in tick 0 and make the first ticks late and their
    actions missed."""
    if central:
        ControlCounters(cfg, 1).round(np.zeros((1, cfg.scenario.n_uavs, 2)))
    # The grid's own mobility even for a replayed trace: the same kernels compile (one step function for both).
    small = cfg.replace(scenario={"n_vehicles": min(cfg.scenario.n_vehicles, 20), "steps_per_episode": 2,
                                  "mobility": "builtin"},
                        roads={"warmup_steps": min(cfg.roads.warmup_steps, 2)})
    world = World(small, 1)
    world.reset([seeding.world_rng(0)])
    done = False
    while not done:
        _, _, done = world.step(np.full((1, small.scenario.n_uavs), HOVER, np.int64))
    world.start_episode()


@functools.lru_cache(maxsize=8)
def _obs_keys(run: str, n_uavs: int) -> tuple[str, ...]:
    return tuple(keys.uav_obs(run, i) for i in range(n_uavs))


def publish_round(bus: Bus, cfg: Config, opts: WorldOptions, world: World, tick: int, episode: int, obs,
                  done: bool) -> None:
    """What the world sends for a tick: its stamp, every UAV's observation and (every
    POSITIONS_EVERY_TICKS ticks) all positions."""
    run, sc, lockstep, n_uavs = opts.run, cfg.scenario, opts.lockstep, cfg.scenario.n_uavs
    period_ms = 1e3 / opts.rate_hz
    bus.publish(keys.world_tick(run), schema.Tick(
        tick=tick, episode=episode, sim_time=tick * sc.step_s,
        deadline_ms=opts.lockstep_wait_s * 1e3 if lockstep else opts.deadline_frac * period_ms,
        n_uavs=n_uavs))
    for key, msg in zip(_obs_keys(run, n_uavs), observation_messages(cfg, tick, episode, obs, done)):
        bus.publish(key, msg)
    if tick % POSITIONS_EVERY_TICKS == 0:
        vehicles = np.round(world.vehicle_xy()[0] / POSITIONS_GRID_M) * POSITIONS_GRID_M
        vehicles = vehicles[np.isfinite(vehicles).all(axis=1)]  # a replayed trace's vehicles not on the road
        bus.publish(keys.world_positions(run), schema.Positions(
            tick=tick, uavs=tuple(map(tuple, obs.pos[0])), vehicles=tuple(map(tuple, vehicles))))


class WorldNode:
    """Drives a one-environment World from bus traffic."""

    def __init__(self, cfg: Config, opts: WorldOptions, bus: Bus, clock=time.monotonic):
        self.cfg, self.opts, self.bus, self.clock = cfg, opts, bus, clock
        self.n_uavs = cfg.scenario.n_uavs
        self.world = make_world(cfg, 1)
        warm_up_kernels(cfg, central=opts.scheme == "central")
        self.stats = WorldStats()
        self._debug = Every(log)
        self._missing: list[int] = []  # the last acting tick's UAVs without an answer (debug lines)
        self.accounts = UavAccounts(self.n_uavs)  # per-UAV counts (under self._cond)
        self._silent: set[int] = set()  # lock-step: live UAVs not waited for (they missed a round) until they answer
        self._miss_logged: set[int] = set()  # UAVs whose first miss was logged
        self._miss_since: dict[int, int] = {}  # UAVs that missed since the last summary line: {uav: ticks}
        self._miss_line = Every(None, MISS_LOG_PERIOD_S, clock)
        self._uav_metrics: dict[str, float] = {}  # the step metrics' worst-UAV values (recomputed when counts move)
        self._uav_metrics_key = None
        self._cond = threading.Condition()
        self._actions: dict[int, int] = {}
        # Overrides heard since the last acting tick, the newest per UAV (a flood costs one entry per UAV).
        self._override_inbox: dict[int, schema.Override] = {}
        self.overrides: dict[int, tuple[float, float, float]] = {}  # UAV -> (x, y, speed) it is steered to
        self._tick = -1
        self._left: dict[str, float] = {}  # token key -> when it vanished (a quick return is no loss)
        self._snapshot_too_large = False  # said once
        self._round = -1  # the latest tick published (its round may have closed: self._tick is then -1)
        self._answered = [-1] * self.n_uavs  # per UAV: the newest tick it answered
        self._alive: set[int] = set()
        self._controller_alive = False
        self._t0 = None
        self._ending = False
        self._stop = threading.Event()
        run = opts.run
        self.central = opts.scheme == "central"
        self._plane = None
        if self.central:
            self._plane = ControlCounters(cfg, 1)
        bus.guard = guard.for_config(cfg)  # senders, value ranges, one action per UAV per tick
        # What it refuses of an agent's messages is told to that agent (at most once per UAV per period).
        self.notices = RejectionNotices(self.n_uavs)
        self._notice_wake = threading.Event()
        bus.on_refused = self._on_refused
        bus.accept_replay = opts.accept_replay
        # Real time: a flood on the action keys costs a bounded amount of work (the oldest samples are
        # dropped inside Zenoh when the world falls behind) instead of a backlog that delays every action.
        bus.receive_ring = None if opts.lockstep else transport.REALTIME_RECEIVE_RING
        plan = load_plan(opts.fault_plan) if opts.fault_plan else None
        self.faults = attach_plan(bus, run, plan, 1.0 / opts.rate_hz)
        bus.subscribe(keys.all_actions(run), self._on_action)
        bus.subscribe(keys.control(run, CONTROL_SHUTDOWN), self._on_control)  # the shutdown, and ...
        bus.subscribe(keys.all_overrides(run), self._on_override)  # ... a UAV steered from outside
        bus.watch_liveliness(keys.all_alive_uavs(run), self._on_join, self._on_leave)
        if self.central:
            bus.watch_liveliness(keys.alive_controller(run), lambda k: self._on_controller(True),
                                 lambda k: self._on_controller(False))
        bus.prepare(keys.world_tick(run), keys.world_positions(run), keys.metrics_step(run),
                    keys.fault(run, schema.FAULT_OVERRIDE),
                    *(keys.uav_obs(run, i) for i in range(self.n_uavs)))
        gc.freeze()  # start-up objects never become garbage: spare the world collector stalls mid-run
        self._notices_closing = threading.Event()
        self._notifier = threading.Thread(target=self._tell_rejections, name="world-rejections", daemon=True)
        self._notifier.start()
        bus.declare_liveliness(keys.alive_world(run))

    # -- bus callbacks (delivery thread: keep short) --
    def _on_action(self, key, msg: schema.Action, raw, recv_ns) -> None:
        if msg.uav >= self.n_uavs:
            return
        with self._cond:
            if msg.tick > self._round:
                return  # a tick not published yet (forged): ignored
            back = msg.uav in self._silent
            if back:  # it answers again: waited for from the next round on
                self._silent.discard(msg.uav)
            newest = self._answered[msg.uav]
            self._answered[msg.uav] = max(newest, msg.tick)
            if msg.tick == self._tick:
                if msg.uav not in self._actions:
                    self._actions[msg.uav] = msg.action
                    self._cond.notify_all()
                first = None
            else:
                stale = msg.tick < newest  # an older answer overtaken by a newer one of the same agent
                if stale:
                    self.stats.stale_actions += 1
                    self.accounts.stale[msg.uav] += 1
                else:
                    self.stats.late_actions += 1
                    self.accounts.late[msg.uav] += 1
                first = (self.stats.stale_actions if stale else self.stats.late_actions) == 1
                self.notices.note(msg.uav, schema.R_STALE_ACTION if stale else schema.R_LATE_ACTION, msg.KIND, key,
                                  msg.tick, "after a newer action of it" if stale else "after its round closed")
                self._notice_wake.set()
        if back:
            log.info("uav %d answered again (tick %d): the world waits for it again", msg.uav, msg.tick)
        if first is None:
            return
        (log.info if first else log.debug)(
            "uav %d's action for tick %d came %s (not applied; counted as %s in the stats)", msg.uav, msg.tick,
            "after a newer one of it (out of order)" if stale else "after its round closed",
            "stale_actions" if stale else "late_actions")

    def _on_override(self, key, msg: schema.Override, raw, recv_ns) -> None:
        """An override (or its release) from outside: applied from the next acting tick on (_steer); of several for
        one UAV before then, the newest."""
        if msg.uav >= self.n_uavs:
            return
        with self._cond:
            self._override_inbox.pop(msg.uav, None)  # the newest last: applied in the order the UAVs were told
            self._override_inbox[msg.uav] = msg

    def _steer(self, tick: int, obs, actions: np.ndarray) -> np.ndarray:
        """``actions`` with every overridden UAV's replaced by world.steer's toward its goal, after taking the
        overrides heard since the last acting tick; each start and end told on fault/override (with the tick it
        applies to: a re-simulation applies it there) and kept in the statistics."""
        with self._cond:
            inbox, self._override_inbox = self._override_inbox, {}
        sc = self.cfg.scenario
        for msg in inbox.values():
            uav = msg.uav
            if msg.release:
                if self.overrides.pop(uav, None) is None:
                    continue  # not overridden: nothing ends
                params = {"tick": tick, "by": msg.src}
                phase = schema.PHASE_END
            else:
                x, y = (min(max(float(v), 0.0), sc.area_m) for v in msg.goal)
                self.overrides[uav] = (x, y, msg.speed)
                params = {"tick": tick, "x": x, "y": y, "speed": msg.speed, "by": msg.src}
                phase = schema.PHASE_START
            self.stats.overrides.append({"uav": uav, "phase": phase, **params})
            self.bus.publish(keys.fault(self.opts.run, schema.FAULT_OVERRIDE), schema.Fault(
                fault=schema.FAULT_OVERRIDE, phase=phase, target=keys.uav_identity(uav), params=params))
            log.info("tick %d: uav %d %s by %s%s", tick, uav,
                     "overridden" if phase == schema.PHASE_START else "released (its agent flies it again)", msg.src,
                     f": steered to ({params['x']:.0f}, {params['y']:.0f}) m" if phase == schema.PHASE_START else "")
        if not self.overrides:
            return actions
        return apply_overrides(actions, obs.pos, self.overrides, sc.uav_speed_mps, sc.step_s, sc.area_m)

    def _on_refused(self, key: str, exc: schema.SchemaError) -> None:
        """A message the bus refused: noted for the UAV of its key (under --secure only that UAV may put there;
        the payload's word is not taken), told by _tell_rejections."""
        facts = facts_of(key)
        if facts.uav is not None:
            self.accounts.note_refused(facts.uav, exc.reason)
            self.notices.note(facts.uav, exc.reason, facts.kind or "", key, self._round, exc.detail or exc.reason)
            self._notice_wake.set()

    def _tell_rejections(self) -> None:
        """Publish the rejections due, at most one per UAV per REJECTION_PERIOD_S, until close_rejections()
        (which lets it send what is still pending first)."""
        notices, wake, run = self.notices, self._notice_wake, self.opts.run
        while True:
            wake.wait()
            wake.clear()
            while notices.pending():
                for msg in notices.due(self.clock()):
                    try:
                        self.bus.publish(keys.uav_rejected(run, msg.uav), msg)
                    except Exception as exc:  # a closed bus: nothing more to tell
                        log.debug("rejection for uav %d not sent: %r", msg.uav, exc)
                        return
                time.sleep(notices.period_s / 2)
            if self._notices_closing.is_set():
                return

    def close_rejections(self, timeout_s: float = 2.0) -> None:
        """Send the rejections still pending (within about REJECTION_PERIOD_S) and end their thread: before
        the session closes."""
        self._notices_closing.set()
        self._notice_wake.set()
        self._notifier.join(timeout_s)

    def _on_control(self, key, msg: schema.Control, raw, recv_ns) -> None:
        if msg.command == CONTROL_SHUTDOWN and msg.src != self.bus.identity:
            log.info("shutdown requested by %s", msg.src)
            self.stop()

    def _scenario_uav(self, key: str) -> int | None:
        """The UAV of a liveliness key, if the scenario has it; a token of another id (an agent started with
        the wrong --id, or a forgery) is counted as refused and ignored: never waited for, never accounted."""
        uav = keys.parse_uav_id(key)
        if uav is not None and uav >= self.n_uavs:
            self.bus.rejections.add(guard.R_IMPLAUSIBLE, keys.uav_identity(uav), key,
                                    f"liveliness token of uav {uav}, the scenario has {self.n_uavs} UAVs")
            return None
        return uav

    def _on_join(self, key: str) -> None:
        uav = self._scenario_uav(key)
        if uav is None:
            return
        with self._cond:
            self._alive.add(uav)
            self._silent.discard(uav)  # a (re)started agent is waited for again
            self.stats.joins.append(key)
            left = self._left.pop(key, None)
            if left is not None and self.clock() - left < REJOIN_S and key in self.stats.losses:
                del self.stats.losses[len(self.stats.losses) - 1 - self.stats.losses[::-1].index(key)]  # its newest
                self.stats.rejoins += 1
            self._cond.notify_all()
        log.info("agent joined: %s", key)

    def _on_leave(self, key: str) -> None:
        uav = self._scenario_uav(key)
        if uav is None:
            return
        with self._cond:
            self._alive.discard(uav)
            self.stats.losses.append(key)
            self._left[key] = self.clock()
            self._cond.notify_all()
        log.warning("agent lost: %s", key)

    def _on_controller(self, up: bool) -> None:
        with self._cond:
            self._controller_alive = up
            if not up and self._t0 is not None and not self._ending:  # leaving on the shutdown is no loss
                self.stats.controller_losses.append(round(self.clock() - self._t0, 2))
            self._cond.notify_all()
        (log.info if up else log.warning)("controller %s", "joined" if up else "lost: UAVs fly on without commands")

    def silent(self) -> set[int]:
        """Lock-step: the live UAVs marked silent (not waited for until they answer again)."""
        with self._cond:
            return set(self._silent)

    def stop(self) -> None:
        self._stop.set()
        with self._cond:
            self._cond.notify_all()

    # -- main loop --
    def wait_for_agents(self) -> int:
        deadline = self.clock() + self.opts.wait_agents_s
        with self._cond:
            while (len(self._alive) < self.n_uavs or (self.central and not self._controller_alive)) \
                    and not self._stop.is_set():
                left = deadline - self.clock()
                if left <= 0:
                    break
                self._cond.wait(min(left, 0.2))
            return len(self._alive)

    def run(self) -> WorldStats:
        opts = self.opts
        period = 1.0 / opts.rate_hz
        n = self.wait_for_agents()
        log.info("%d/%d agents alive%s; starting %s", n, self.n_uavs,
                 ("" if not self.central else ", controller " + ("alive" if self._controller_alive else "MISSING")),
                 "lock-step" if opts.lockstep else f"{opts.rate_hz:g} Hz")
        obs = self.world.reset([seeding.world_rng(opts.seed)])
        tick, next_due = 0, self.clock()
        self._t0 = self.clock()
        self.stats.first_tick_wall_s = time.time()
        for episode in range(opts.episodes):
            if episode:
                obs = self.world.start_episode()
            if self._plane is not None:
                self._plane.reset()
            digest = action_digest()
            done = False
            while not done and not self._stop.is_set():
                if not opts.lockstep:
                    start, next_due = self._await_tick(next_due, period, tick)
                    deadline = start + opts.deadline_frac * period
                actions = self._steer(tick, obs, self._tick_round(tick, episode, obs, False,
                                                                  None if opts.lockstep else deadline))
                digest.update(np.ascontiguousarray(actions[0], np.int64).tobytes())
                obs, metrics, done = self.world.step(actions, *self._control_round(obs))
                self._publish_step(tick, episode, metrics, actions)
                tick += 1
            if self._stop.is_set():
                break
            # The episode's last observation: agents learn from it but do not act.  In real time it
            # waits for its own tick: sent at once, its 20 deliveries and learning steps would land
            # among the last tick's beacon slots.
            if not opts.lockstep:
                _, next_due = self._await_tick(next_due, period, tick)
            self._tick_round(tick, episode, obs, True, None)
            tick += 1
            summary = {k: float(v[0]) for k, v in self.world.episode_summary().items()}
            if self._plane is not None:  # the modelled control plane, as the in-process central reports it
                summary.update({k: float(v[0]) for k, v in self._plane.stats().items()})
            self.stats.episodes.append(summary)
            self.stats.actions_digest.append(digest.hexdigest())
            self.stats.end_positions.append(obs.pos[0].tolist())
            self.bus.publish(keys.metrics_episode(opts.run), schema.Metrics(
                scope=schema.SCOPE_EPISODE, tick=tick, episode=episode,
                values={k: v for k, v in summary.items() if np.isfinite(v)}))
            log.info("episode %d: coverage %s%% pdr %s delay %s ms", episode, shown(summary["coverage_pct"], ".1f"),
                     shown(summary["pdr"], ".3f"), shown(summary["delay_ms"], ".0f"))
        self.stats.ticks = tick
        self.stats.overridden_at_end = sorted(self.overrides)
        self.stats.last_tick_wall_s = time.time()
        if not opts.lockstep:  # let the last tick run its period: agents are still learning from it
            self._sleep_until(next_due)
        with self._cond:
            self._ending = True
        self.close_rejections()  # told before the shutdown, on which the agents leave
        self.bus.publish(keys.control(opts.run, CONTROL_SHUTDOWN), schema.Control(command=CONTROL_SHUTDOWN, args={}))
        return self.stats

    def _control_round(self, obs) -> tuple:
        """(control_airtime_s, action_delay_s) for World.step: the model's round on the central scheme's
        round steps (as agents.central.CentralController.control does in process), else none."""
        if self._plane is None or self.world.t % self.cfg.central.update_period_steps:
            return None, 0.0
        return self._plane.round(obs.pos)

    def _await_tick(self, due: float, period: float, tick: int) -> tuple[float, float]:
        """Real time: sleep until the tick due at ``due``, record how late it starts; (when this tick starts,
        the next one's due time). A start a whole period late or more resumes from now (see STALL_MIN_S)."""
        self._sleep_until(due)
        now = self.clock()
        late = now - due
        self.stats.tick_lateness_ms.append(late * 1e3)
        if late < period:
            return due, due + period
        skipped = int(late // period)
        self.stats.ticks_skipped += skipped
        if late >= STALL_MIN_S:
            self.stats.stalls.append({"tick": tick, "s": round(late, 3), "ticks_skipped": skipped})
            log.warning("tick %d: the world's clock jumped %.1f s (it was paused, or the host stalled); resuming "
                        "from now: %d tick(s) skipped, not sent in a burst", tick, late, skipped)
        return now, now + period

    def _sleep_until(self, due: float) -> None:
        while not self._stop.is_set():
            left = due - self.clock()
            if left <= 0:
                return
            self._stop.wait(min(left, 0.05))

    def _publish_snapshot(self, tick: int, episode: int, obs) -> None:
        """The world's state before ``tick``'s round, for `truav log resim --from` (once per snapshot tick)."""
        state = world_state(self.world, obs)
        if not fits(state):
            if not self._snapshot_too_large:
                log.warning("world state of %d bytes does not fit one snapshot message (%d): not published",
                            sum(a.nbytes for a in state.values()), schema.MAX_SNAPSHOT_BYTES)
            self._snapshot_too_large = True
            return
        self.bus.publish(keys.world_snapshot(self.opts.run), world_snapshot(tick, episode, state))

    def _tick_round(self, tick: int, episode: int, obs, done: bool, deadline: float | None) -> np.ndarray:
        """Publish tick + observations; return the actions (B=1, U), HOVER where missing.

        Lock-step waits for an answer to the ``done`` observation too (an acknowledgement, not applied):
        the next tick goes out only once every agent alive at publication has finished this one."""
        lockstep = self.opts.lockstep
        with self._cond:
            self._tick = tick if lockstep or not done else -1
            self._round = tick
            self._actions = {}
            # One who joins later never saw this tick's observation; one marked silent is not waited for.
            expected = set(self._alive) - self._silent
            alive = set(self._alive)
        if snapshot_due(lockstep, self.opts.snapshot_every, tick):
            self._publish_snapshot(tick, episode, obs)
        publish_round(self.bus, self.cfg, self.opts, self.world, tick, episode, obs, done)
        actions = np.full((1, self.n_uavs), HOVER, np.int64)
        if done and not lockstep:
            return actions
        limit = self.clock() + self.opts.lockstep_wait_s if deadline is None else deadline
        waiting: set[int] = set()
        with self._cond:
            while not self._stop.is_set():
                waiting = (expected & self._alive) - set(self._actions) if deadline is None else \
                    set(range(self.n_uavs)) - set(self._actions)
                left = limit - self.clock()
                if not waiting or left <= 0:
                    break
                self._cond.wait(min(left, 0.05))
            answered = dict(self._actions)
            self._tick = -1
            stopped = self._stop.is_set()
            silenced = sorted(waiting) if lockstep and waiting and not stopped else []
            self._silent.update(silenced)
            acc = self.accounts
            if done:
                if lockstep and not stopped:
                    unacked = alive - set(answered)  # not waited for (silent) or given up on: missed all the same
                    self.stats.acks_missed += len(unacked)
                    for uav in unacked:
                        acc.missed[uav] += 1
            else:
                for uav in answered:
                    acc.applied[uav] += 1
                missing = [uav for uav in range(self.n_uavs) if uav not in answered]
                for uav in missing:
                    acc.missed[uav] += 1
        if silenced:  # the run is no longer exactly reproducible: say so
            st = self.stats
            st.lockstep_missed += len(silenced)
            st.silent_marked += len(silenced)
            if st.lockstep_missed_from_tick is None:
                st.lockstep_missed_from_tick = tick
            log.warning("tick %d: no %s from live agent(s) %s within %.1f s; going on without them (the run is no "
                        "longer exact); marked silent: later ticks do not wait for them until they answer again",
                        tick, "acknowledgement" if done else "action", _uav_list(silenced), self.opts.lockstep_wait_s)
        if done:
            return actions
        for uav, a in answered.items():
            actions[0, uav] = a
        self.stats.hover_answers += sum(1 for a in answered.values() if a == HOVER)
        self.stats.actions_received += len(answered)
        self.stats.deadline_misses += len(missing)  # no answer: hovers
        self._missing = missing
        if missing and not stopped:
            self._log_missed(tick, missing)
        return actions

    def _log_missed(self, tick: int, missing: list[int]) -> None:
        """A UAV's first missed tick at once, naming it; then a summary line at most every MISS_LOG_PERIOD_S."""
        first = [uav for uav in missing if uav not in self._miss_logged]
        self._miss_logged.update(first)
        for uav in missing:
            self._miss_since[uav] = self._miss_since.get(uav, 0) + 1
        if first:
            log.warning("tick %d: no action in time from uav %s (they hover)%s", tick, _uav_list(first),
                        "; each UAV's first miss is logged, then a summary at most every %gs" % MISS_LOG_PERIOD_S
                        if len(self._miss_logged) == len(first) else "")
            self._miss_line.due()  # the summary's period starts now
        elif self._miss_line.due() and self._miss_since:
            since = sorted(self._miss_since.items(), key=lambda kv: (-kv[1], kv[0]))
            with self._cond:
                totals = {uav: self.accounts.missed[uav] for uav, _ in since[:MISS_LOG_MAX_NAMED]}
            named = ", ".join(f"uav {uav} {totals[uav]}" for uav, _ in since[:MISS_LOG_MAX_NAMED])
            more = len(since) - MISS_LOG_MAX_NAMED
            log.warning("tick %d: %d UAV(s) missed actions since the last such line (they hover); missed so far: "
                        "%s%s", tick, len(since), named, f" and {more} more" if more > 0 else "")
            self._miss_since = {}

    def uav_metrics(self) -> dict[str, float]:
        """The step metrics' ``uav.<i>.<count>`` values for the worst UAVs (UavAccounts.worst_metrics), recomputed
        only when a count moved."""
        acc = self.accounts
        with self._cond:
            mark = (self.stats.deadline_misses, self.stats.acks_missed, self.stats.late_actions,
                    self.stats.stale_actions, acc.refused_total)
            if mark != self._uav_metrics_key:
                self._uav_metrics_key = mark
                self._uav_metrics = acc.worst_metrics()
            return self._uav_metrics

    def _publish_step(self, tick, episode, m, actions) -> None:
        values = {"covered": float(m.covered[0]), "generated": float(m.generated[0]),
                  "delivered": float(m.delivered[0]), "dropped": float(m.dropped_overflow[0] + m.dropped_deadline[0]),
                  "delay_sum_s": float(m.delay_sum_s[0]), "energy_j": float(m.energy_j[0].mean()),
                  "hovering_uavs": float(len(self._missing)),  # no action heard: they hover (not a chosen HOVER)
                  "coverage_pct": 100.0 * float(m.covered[0]) / self.cfg.scenario.n_vehicles,
                  **rejection_metrics(self.bus.rejections), **self.uav_metrics()}
        self.bus.publish(keys.metrics_step(self.opts.run), schema.Metrics(
            scope=schema.SCOPE_STEP, tick=tick, episode=episode, values=values))
        if self._debug.due():
            late = "lock-step" if self.opts.lockstep else f"started {self.stats.tick_lateness_ms[-1]:.1f} ms late"
            log.debug("tick %d (episode %d, %s): sent tick + %d observations; received actions %s "
                      "(missing: %s, they hover); stepped: coverage %.1f%%, packets %d generated %d delivered",
                      tick, episode, late, self.n_uavs, actions[0].tolist(), self._missing or "none",
                      values["coverage_pct"], values["generated"], values["delivered"])


def _uav_list(uavs: list[int]) -> str:
    """"3, 7, 12" (at most MISS_LOG_MAX_NAMED, then "and N more")."""
    shown = ", ".join(map(str, uavs[:MISS_LOG_MAX_NAMED]))
    return shown + (f" and {len(uavs) - MISS_LOG_MAX_NAMED} more" if len(uavs) > MISS_LOG_MAX_NAMED else "")


__all__ = ["WorldNode", "WorldOptions", "WorldStats", "action_digest", "publish_round", "warm_up_kernels",
           "write_stats"]

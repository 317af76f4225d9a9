"""The centralized baseline's controller as an OS process on the Zenoh bus (`truav-swarm controller`).

It runs the in-process driver's own controller, agents.central.CentralController
with B = 1 (its soft actor-critic, joint state and reward), fed from the bus:
every UAV uploads its local state on ``uav/<i>/state`` each control round
(agents.process.scheme_process.CentralAgentNode); once a tick's uploads are in, the
controller calls ``begin_episode`` / ``observe`` / ``act`` exactly as the
in-process driver does and publishes one command per UAV on
``controller/cmd/<i>``, padded to ``central.download_bytes``. The radio effects
of these messages (airtime, action delay) are the world's business: it applies
the same control-plane model as the in-process driver (world.process.world_process).

- Lock-step: a tick is decided once the upload of every UAV not known gone is in
  (one silent for 10 s is decided without, with a warning).
- Real time: once all uploads of the tick are in, or ``collect_frac`` of the
  tick period after the first of them arrived; a missing UAV's last upload
  stands in for it (counted as ``stale_states``). After a stall only the
  newest two ticks waiting are decided (the older ones: ``skipped_ticks``).
- Policy: a trained actor (``--policy RUN``: `truav train --scheme central`),
  flown greedily, or, without one, learning online from the uploads (random
  actions for the first ``central.learning_starts`` steps, as in process).
  With ``central.update_period_steps`` > 1 the UAVs upload on round steps only,
  so an online learner learns from those alone (the in-process one sees every step).
"""

from __future__ import annotations

import gc
import logging
import threading
import time
from pathlib import Path

import numpy as np

from agents.process.agent_process_lockstep import Inexact
from agents.process.controller_options import ControllerOptions
from truav import jsonio
from truav.analysis import runio
from truav.analysis.trainer import make_controller  # the in-process driver's controller (with central.geofence too)
from truav.atomic import write_atomic_text
from truav.bus.fault_filter import attach_plan
from truav.bus.transport import Bus
from truav.config import Config
from truav.faults import load_plan
from truav.lograte import Every
from truav.wire import guard, keys, schema
from world.env import LocalObs

log = logging.getLogger("truav.controller")

CONTROL_SHUTDOWN = "shutdown"


def warm_up_learning(cfg: Config) -> None:
    """Compile (or load from the cache) every kernel an online-learning controller runs (joint state, reward,
    sampled actions, replay store, an update) on a throwaway tiny learner with its own generator, before
    joining: on a cold cache that takes most of a second, which would otherwise make the first ticks' commands
    late. numba specialises on dtypes and ranks, not sizes, so the real learner then compiles nothing."""
    tiny = cfg.replace(central={"hidden": 4, "batch_size": 2, "buffer_size": 2, "learning_starts": 0,
                                "update_every": 1})
    probe = make_controller("central", tiny, [0], True, None)
    U = cfg.scenario.n_uavs
    obs = LocalObs(pos=np.zeros((1, U, 2)), vehicles_in_range=np.zeros((1, U), np.int64),
                   queued=np.zeros((1, U), np.int64), relayed=np.zeros((1, U), np.int64),
                   covered=np.zeros((1, U), np.int64), energy_j=np.zeros((1, U)))
    probe.begin_episode(0, obs)
    probe.act(0)
    probe.observe(obs, False)
    probe.act(1)


class ControllerNode:
    def __init__(self, cfg: Config, opts: ControllerOptions, bus: Bus):
        self._debug = Every(log)
        self.cfg, self.opts, self.bus = cfg, opts, bus
        self.n_uavs = cfg.scenario.n_uavs
        params = runio.read_policy(opts.policy, opts.policy_index, cfg) if opts.policy else None
        self.central = make_controller("central", cfg, [opts.seed], params is None, params)
        # torch's first forward pass (cold: most of a second) before joining, not in tick 0; greedy draws nothing.
        self.central.sac.act(np.zeros((1, self.central.critic_input_dim)), greedy=True)
        if params is None:
            warm_up_learning(cfg)
        self._cond = threading.Condition()
        self._by_tick: dict[int, dict[int, schema.State]] = {}
        self._first_at: dict[int, float] = {}
        self._last: dict[int, schema.State] = {}
        self._gone: set[int] = set()  # UAVs whose liveliness token vanished (a slow starter is not one)
        self._done_tick = -1
        self._episode = -1
        self._stop = threading.Event()
        self.inexact = Inexact()  # lock-step: decisions taken without a live UAV's upload (controller.json)
        self.stats = {"ticks": 0, "commands": 0, "states": 0, "stale_states": 0, "late_states": 0, "skipped_ticks": 0,
                      "episodes": 0, "decide_ms": [], "policy": opts.policy or "online learning"}
        run = opts.run
        bus.guard = guard.for_config(cfg)
        bus.accept_replay = opts.accept_replay
        self.faults = attach_plan(bus, run, load_plan(opts.fault_plan) if opts.fault_plan else None,
                                  opts.tick_period_s)
        bus.subscribe(keys.all_states(run), self._on_state)
        # The world's ticks keep the guard's tick window current (it learns the tick from them and from the
        # commands sent): a controller stalled for more than the window would otherwise refuse every later
        # upload as out of the window, and never decide again.
        bus.subscribe(keys.world_tick(run), lambda *_: None)
        bus.subscribe(keys.all_control(run), self._on_control)
        bus.watch_liveliness(keys.all_alive_uavs(run), self._on_join, self._on_leave)
        bus.prepare(*(keys.controller_cmd(run, i) for i in range(self.n_uavs)))
        gc.freeze()
        bus.declare_liveliness(keys.alive_controller(run))

    # -- bus callbacks (delivery thread: keep short) --
    def _on_state(self, key, msg: schema.State, raw, recv_ns) -> None:
        with self._cond:
            self.stats["states"] += 1
            if msg.tick <= self._done_tick or msg.uav >= self.n_uavs:
                self.stats["late_states"] += 1
                return
            self._by_tick.setdefault(msg.tick, {})[msg.uav] = msg
            self._first_at.setdefault(msg.tick, time.monotonic())
            self._cond.notify_all()

    def _on_control(self, key, msg: schema.Control, raw, recv_ns) -> None:
        if msg.command == CONTROL_SHUTDOWN:
            log.info("controller: shutdown from %s", msg.src)
            self.stop()

    def _on_join(self, key: str) -> None:
        uav = keys.parse_uav_id(key)
        with self._cond:
            if uav is not None:
                self._gone.discard(uav)
                self._cond.notify_all()

    def _on_leave(self, key: str) -> None:
        uav = keys.parse_uav_id(key)
        with self._cond:
            if uav is not None:
                self._gone.add(uav)
                self._cond.notify_all()
        log.warning("controller: uav %s lost", uav)

    def stop(self) -> None:
        self._stop.set()
        with self._cond:
            self._cond.notify_all()

    # -- main loop --
    def run(self) -> None:
        while not self._stop.is_set():
            got = self._next_tick()
            if got is not None:
                self.decide(*got)

    def _next_tick(self) -> tuple[int, dict[int, schema.State]] | None:
        """The oldest tick whose uploads are complete (or waited for long enough), taken out of the buffer."""
        with self._cond:
            while not self._stop.is_set():
                if self._by_tick:
                    # Real time: after a stall, only the newest ticks are worth deciding (a command for a
                    # tick long gone is not flown); the older ones are skipped, counted.
                    while not self.opts.lockstep and len(self._by_tick) > 2:
                        old = min(self._by_tick)
                        del self._by_tick[old], self._first_at[old]
                        self._done_tick = max(self._done_tick, old)
                        self.stats["skipped_ticks"] += 1
                    tick = min(self._by_tick)
                    got = self._by_tick[tick]
                    waited = time.monotonic() - self._first_at[tick]
                    if self.opts.lockstep:
                        missing = set(range(self.n_uavs)) - self._gone - set(got) \
                            if waited < self.opts.lockstep_wait_s else set()
                        limit = self.opts.lockstep_wait_s
                    else:
                        missing = set(range(self.n_uavs)) - set(got)
                        limit = self.opts.collect_frac * self.opts.tick_period_s
                    # A later tick already arriving means this one's stragglers are not coming.
                    if not missing or waited >= limit or len(self._by_tick) > 1:
                        late = set(range(self.n_uavs)) - self._gone - set(got)
                        if late and self.opts.lockstep and waited >= limit:
                            self.inexact.add(tick)
                            log.warning("tick %d: no upload from live uav(s) %s within %.1f s; deciding without "
                                        "(the run is no longer exact)", tick, sorted(late), limit)
                        del self._by_tick[tick], self._first_at[tick]
                        self._done_tick = tick
                        return tick, got
                    self._cond.wait(min(limit - waited, 0.05))
                else:
                    self._cond.wait(0.05)
        return None

    def decide(self, tick: int, got: dict[int, schema.State]) -> None:
        """The in-process driver's calls for one tick's uploads, then a command per UAV on a round."""
        t0 = time.perf_counter()
        self._last.update(got)
        if len(self._last) < self.n_uavs:  # a UAV never heard yet: nothing to decide from
            log.warning("tick %d: no upload ever heard from uav(s) %s; no commands", tick,
                        sorted(set(range(self.n_uavs)) - set(self._last)))
            return
        self.stats["stale_states"] += self.n_uavs - len(got)
        states = [self._last[i] for i in range(self.n_uavs)]
        mine = list(got.values())
        episode, step, done = mine[0].episode, mine[0].step, any(s.done for s in mine)
        obs = LocalObs(pos=np.array([[s.pos for s in states]], np.float64),
                       vehicles_in_range=np.array([[s.vehicles_in_range for s in states]], np.int64),
                       queued=np.array([[s.queued_packets for s in states]], np.int64),
                       relayed=np.array([[s.relayed for s in states]], np.int64),
                       covered=np.array([[s.covered for s in states]], np.int64),
                       energy_j=np.array([[s.energy_j for s in states]], np.float64))
        c = self.central
        if episode != self._episode:
            self._episode = episode
            self.stats["episodes"] += 1
            c.begin_episode(episode, obs)
        else:
            c.observe(obs, done)
        self.stats["ticks"] += 1
        if done:
            return
        actions = c.act(step)[0]
        run, size = self.opts.run, self.cfg.central.download_bytes
        for i in range(self.n_uavs):
            self.bus.publish(keys.controller_cmd(run, i), schema.Command(uav=i, tick=tick, action=int(actions[i]),
                                                                         pad=b""), pad_to=size)
        self.stats["commands"] += self.n_uavs
        self.stats["decide_ms"].append((time.perf_counter() - t0) * 1e3)
        if self._debug.due():
            log.debug("controller tick %d (episode %d, step %d): received uploads of uav %s (%d stale so far); "
                      "decided in %.1f ms; sent commands %s", tick, episode, step, sorted(got),
                      self.stats["stale_states"], self.stats["decide_ms"][-1], [int(a) for a in actions])

    def write_stats(self) -> None:
        if not self.opts.stats_out:
            return
        data = dict(self.stats)
        if self.opts.lockstep:
            data["lockstep"] = self.inexact.as_dict()
        ms = np.array(data.pop("decide_ms"))
        if ms.size:
            data["decide_ms"] = {"p50": float(np.percentile(ms, 50)), "p99": float(np.percentile(ms, 99)),
                                 "max": float(ms.max()), "n": int(ms.size)}
        data["rejected"] = self.bus.rejections.as_dict()
        data["bus"] = {"filtered": self.bus.stats().filtered, "delayed": self.bus.stats().delayed}
        p = Path(self.opts.stats_out)
        write_atomic_text(p, jsonio.dumps(data, indent=1))

"""The agent processes of the two baselines on the bus: the same process as TRUAV's
(agents.process.agent_process.AgentNode: observations in, one action per tick out, the same
lock-step protocol), flying another scheme's code.

- ``patrol`` (:class:`PatrolAgentNode`): the trajectory-knowledge plan of
  agents.patrol.PatrolController, the in-process driver's own object with B = 1.
  At each deployment (an episode's first tick) every agent sends a beacon with
  its start position (stamped with that tick) and plans from the start
  positions heard: the plan's matching of UAVs to orbits
  (``patrol.assignment = "nearest"``) and its horizon depend on all of them,
  exactly as in process. In real time it repeats that deployment beacon on the
  next DEPLOY_REPEATS ticks and re-plans whenever a start it lacked arrives, so
  a lost or delayed deployment beacon costs a few ticks of a worse plan, not the
  episode. Apart from that it needs nothing but its own observation: no
  beacons, no controller.
- ``central`` (:class:`CentralAgentNode`): uploads its local state to the
  controller (agents.process.central_process) on every control round, ``uav/<i>/state``,
  padded to ``central.upload_bytes``, and flies the latest command
  (``controller/cmd/<i>``). Without a fresh command it does what an autopilot
  does when its link stops: keeps the last commanded action for
  ``command_hold_s`` seconds of the world's clock after the tick it was for,
  then hovers (an explicit HOVER action). It never learns and has no checkpoint.
"""

from __future__ import annotations

import logging
import threading
import time

import numpy as np

from agents.patrol import PatrolController
from agents.process.agent_process import AgentNode, AgentOptions, DONE_ACK_ACTION
from truav.analysis.agent_loader import AGENT_KIND_PREFIX
from truav.bus.transport import Bus
from truav.config import Config
from truav.wire import keys, schema

log = logging.getLogger("truav.agent")

SCHEMES = ("truav", "patrol", "central")
DEPLOY_WAIT_FRAC = 0.3
"""Patrol, real time: wait up to this fraction of the tick period for the peers' deployment beacons."""
DEPLOY_REPEATS = 5
"""Patrol, real time: the deployment beacon goes out again on this many ticks after the first."""


class _NoLearner(AgentNode):
    """An agent without a Q-table: nothing to warm up, load or checkpoint."""

    def _make_learners(self):
        return None

    def _warm_up(self) -> None:
        pass

    def checkpoint(self) -> None:
        pass

    def _ack_done(self, obs: schema.Obs) -> None:
        if self.opts.lockstep:  # the world waits for every agent's acknowledgement before the next tick
            self.bus.publish(keys.uav_action(self.opts.run, self.opts.uav),
                             schema.Action(uav=self.opts.uav, tick=obs.tick, action=DONE_ACK_ACTION))

    def _next_step(self, obs: schema.Obs) -> bool:
        """Count the step; True at an episode's first observation."""
        if obs.episode != self._episode:
            self._episode, self._t = obs.episode, 0
            return True
        self._t += 1
        self.steps += 1
        return False

    def _act(self, obs: schema.Obs, action: int) -> None:
        self._action = action
        self.bus.publish(keys.uav_action(self.opts.run, self.opts.uav),
                         schema.Action(uav=self.opts.uav, tick=obs.tick, action=action))
        if self._debug.due():
            log.debug("uav %d tick %d: received obs at (%.0f, %.0f) m, %d vehicles in range; sent action %d (%s)",
                      self.opts.uav, obs.tick, *obs.pos, obs.vehicles_in_range, action, self._why())

    def _why(self) -> str:
        """Where the scheme's action came from, for the debug line."""
        return self.opts.scheme


class PatrolAgentNode(_NoLearner):
    def _make_learners(self):
        self.patrol = PatrolController(self.cfg, [self.opts.seed])
        self.deployments = 0
        self.deployments_incomplete = 0
        self.replans = 0
        self._known: set[int] = set()
        return None

    def handle(self, obs: schema.Obs) -> None:
        T = self.cfg.scenario.steps_per_episode
        if self._next_step(obs):
            self._deployment(obs)
        elif not self.opts.lockstep:
            self._late_starts(obs)
        if obs.done:
            self._ack_done(obs)
            return
        self._act(obs, self.patrol.act_one(min(self._t, T - 1), 0, self.opts.uav, obs.pos))

    def _deployment(self, obs: schema.Obs) -> None:
        """Plan from every UAV's start position (U, 2): own, and the peers' from this tick's beacons (a
        peer not heard yet is planned at the centre of the area, until its start arrives)."""
        o, sc = self.opts, self.cfg.scenario
        self._starts = np.full((self.n_uavs, 2), sc.area_m / 2.0)
        self._starts[o.uav] = obs.pos
        self._deploy = schema.Beacon(uav=o.uav, tick=obs.tick, pos=obs.pos, vel=(0.0, 0.0))
        self.bus.publish(keys.uav_beacon(o.run, o.uav), self._deploy)
        heard = self._lockstep_beacons(obs.tick) if o.lockstep else self._realtime_beacons(obs.tick)
        for j, b in heard.items():
            self._starts[j] = b.pos
        self._known = {o.uav, *heard}
        self.deployments += 1
        missing = [j for j in range(self.n_uavs) if j not in self._known]
        if missing:
            self.deployments_incomplete += 1
            log.warning("uav %d, episode %d: no deployment beacon from %s yet; planning them at the centre",
                        o.uav, obs.episode, missing)
        self.patrol.plan_env(0, self._starts)

    def _late_starts(self, obs: schema.Obs) -> None:
        """Real time: repeat the deployment beacon for a few ticks; re-plan when a missing start arrives."""
        o = self.opts
        if self._t <= DEPLOY_REPEATS and not obs.done:
            self.bus.publish(keys.uav_beacon(o.run, o.uav), self._deploy)
        # Drained every tick, all starts known or not: the inbox checks a beacon's tick when drained, so
        # the peers' repeats left in it would be refused as stale (tick_out_of_window) at the next deployment.
        self._take_beacons()
        if len(self._known) == self.n_uavs:
            return
        with self._lock:
            late = {j: b for j, b in self._beacons.items() if b.tick == self._deploy.tick and j not in self._known}
        if late:
            for j, b in late.items():
                self._starts[j] = b.pos
            self._known |= set(late)
            self.replans += 1
            self.patrol.plan_env(0, self._starts)

    def _realtime_beacons(self, tick: int) -> dict[int, schema.Beacon]:
        deadline = time.monotonic() + DEPLOY_WAIT_FRAC * self.opts.tick_period_s
        while True:
            self._take_beacons()
            with self._lock:
                got = {j: b for j, b in self._beacons.items() if b.tick == tick}
                missing = [j for j in range(self.n_uavs) if j != self.opts.uav and j not in self._gone and j not in got]
            left = deadline - time.monotonic()
            if not missing or left <= 0 or self._stop.is_set():
                return got
            self._beacon_inbox.wait(min(left, 0.01))

    def _why(self) -> str:
        return f"the patrol plan, from {len(self._known)} of {self.n_uavs} start positions"

    def scheme_stats(self) -> dict:
        return {"deployments": self.deployments, "deployments_incomplete": self.deployments_incomplete,
                "replans": self.replans}


class CentralAgentNode(_NoLearner):
    def _make_learners(self):
        self.commands_fresh = self.commands_held = self.commands_hovered = 0
        self._latest: tuple[int, int] | None = None  # (tick, action) of the newest command heard
        self._round_tick = -1
        self._cmd = threading.Condition()
        self._controller_up = False
        self._controller_seen = False  # its token has been seen at least once (the watch reports it asynchronously)
        self._controller_never_came = False  # lock-step waited its bound for a first sight, in vain
        return None

    def _setup_scheme(self, bus: Bus) -> None:
        run, me = self.opts.run, self.opts.uav
        bus.subscribe(keys.controller_cmd(run, me), self._on_command)
        bus.watch_liveliness(keys.alive_controller(run), lambda k: self._on_controller(True),
                             lambda k: self._on_controller(False))
        bus.prepare(keys.uav_state(run, me))

    def _on_command(self, key, msg: schema.Command, raw, recv_ns) -> None:
        with self._cmd:
            if self._latest is None or msg.tick > self._latest[0]:
                self._latest = (msg.tick, msg.action)
                self._cmd.notify_all()

    def _on_controller(self, up: bool) -> None:
        with self._cmd:
            self._controller_up = up
            self._controller_seen = self._controller_seen or up
            self._cmd.notify_all()
        (log.info if up else log.warning)("uav %d: controller %s", self.opts.uav, "joined" if up else "lost")

    def stop(self) -> None:
        super().stop()
        with self._cmd:
            self._cmd.notify_all()

    def handle(self, obs: schema.Obs) -> None:
        o, c = self.opts, self.cfg.central
        self._next_step(obs)
        is_round = self._t % c.update_period_steps == 0
        if is_round or obs.done:  # the done state too: an online learner learns from the last step
            self.bus.publish(keys.uav_state(o.run, o.uav), schema.State(
                uav=o.uav, tick=obs.tick, episode=obs.episode, step=self._t, pos=obs.pos,
                vehicles_in_range=obs.vehicles_in_range, queued_packets=obs.queued_packets, relayed=obs.relayed,
                covered=obs.covered, energy_j=obs.energy_j, done=obs.done, pad=b""), pad_to=c.upload_bytes)
        if obs.done:
            self._ack_done(obs)
            return
        if is_round:
            self._round_tick = obs.tick
            self._await_command(obs)
        self._act(obs, self._fly(obs))

    def _await_command(self, obs: schema.Obs) -> None:
        if self.opts.lockstep:
            deadline = time.monotonic() + self.opts.lockstep_wait_s  # while the controller is alive
        else:  # the world's stamp of the observation is the tick's start, in its wall clock
            deadline = time.monotonic() + obs.t / 1e9 + self.opts.command_wait_frac * self.opts.tick_period_s \
                - time.time()
        with self._cmd:
            while not self._stop.is_set():
                if self._latest is not None and self._latest[0] >= obs.tick:
                    return
                if self.opts.lockstep and not self._controller_up and \
                        (self._controller_seen or self._controller_never_came):
                    return  # it was lost (or never came): no one will answer, fly on without waiting
                left = deadline - time.monotonic()
                if left <= 0:
                    if self.opts.lockstep:  # a live controller's command did not come: no longer exact
                        self.inexact.add(obs.tick)
                        if not self._controller_seen:  # the world saw it before tick 0; this agent never did
                            self._controller_never_came = True
                        log.warning("uav %d, tick %d: no command from the %s controller within %.1f s; flying "
                                    "on without (the run is no longer exact)", self.opts.uav, obs.tick,
                                    "live" if self._controller_seen else "never seen", self.opts.lockstep_wait_s)
                    return
                self._cmd.wait(min(left, 0.05))

    def _fly(self, obs: schema.Obs) -> int:
        """The action to fly: the current round's command, else the last one while it is recent enough, else hover."""
        with self._cmd:
            latest = self._latest
        if latest is not None and latest[0] >= self._round_tick:
            self.commands_fresh += 1
            return latest[1]
        if latest is not None and (obs.tick - latest[0]) * self.cfg.scenario.step_s <= self.opts.command_hold_s:
            self.commands_held += 1
            return latest[1]
        self.commands_hovered += 1
        return schema.HOVER

    def _why(self) -> str:
        return (f"commands so far: {self.commands_fresh} fresh, {self.commands_held} held, "
                f"{self.commands_hovered} hovered for want of one")

    def scheme_stats(self) -> dict:
        return {"commands": {"fresh": self.commands_fresh, "held": self.commands_held,
                             "hovered": self.commands_hovered}}


def make_agent_node(cfg: Config, opts: AgentOptions, bus: Bus, beacon_inbox=None, **shared) -> AgentNode:
    """The agent process's node for ``opts.scheme`` (``beacon_inbox`` and ``shared``'s switches: see AgentNode)."""
    if opts.scheme.startswith(AGENT_KIND_PREFIX):  # an agents.api class (truav-swarm up --agent NAME)
        from agents.process.api_process import ApiAgentNode
        return ApiAgentNode(cfg, opts, bus, beacon_inbox=beacon_inbox, **shared)
    cls = {"truav": AgentNode, "patrol": PatrolAgentNode, "central": CentralAgentNode}[opts.scheme]
    return cls(cfg, opts, bus, beacon_inbox=beacon_inbox, **shared)


__all__ = ["SCHEMES", "PatrolAgentNode", "CentralAgentNode", "make_agent_node"]

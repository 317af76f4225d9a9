"""The agent process of `truav-swarm up --agent NAME`: an agents.api class flying one UAV on the bus.

The same process as TRUAV's (agents.process.agent_process.AgentNode: observations in, a beacon and one action
per tick out, the lock-step protocol, fault plans, health and stats), deciding with
agents.api_decision.ApiDecision. The class was checked before the swarm started (truav.analysis.agent_loader).
When it raises, returns an illegal action or takes longer than its call_limit_s during the run, this UAV
hovers for that tick, the error is counted and its first occurrence logged with the class's message, and
the run goes on.
It can start from the state a run of `truav train --agent NAME` learned (--qtable RUN: seed
--qtable-index's state of this UAV). Its checkpoint (--checkpoint) holds the agent's state_dict, its generator and its step count: a
restarted agent resumes from it.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path

import numpy as np

from agents.api_decision import ApiDecision, IllegalAction
from agents.process.agent_process import AgentNode, checkpoint_due
from truav.analysis.agent_loader import AGENT_KIND_PREFIX, resolve
from truav.analysis.agent_run import agent_start_states
from truav.call_limit import CallTooLong, call_limited
from truav.wire import keys, schema

log = logging.getLogger("truav.agent")

STATE_PREFIX = "state."


class ApiAgentNode(AgentNode):
    def _make_learners(self):
        o = self.opts
        self.agent_name = o.scheme[len(AGENT_KIND_PREFIX):]
        self.api = ApiDecision(resolve(self.agent_name), self.cfg, o.uav, o.seed, o.train)
        self.agent_errors = 0
        self.first_agent_error: str | None = None
        if o.checkpoint and Path(o.checkpoint).is_file():  # checked readable by the command (check_checkpoint)
            with np.load(o.checkpoint, allow_pickle=False) as ck:
                state = {k[len(STATE_PREFIX):]: ck[k] for k in ck.files if k.startswith(STATE_PREFIX)}
                rng_state, steps = json.loads(str(ck["rng_state"])), int(ck["steps"])
            try:
                call_limited(self.api.limit_s, self.api.agent.load_state_dict, state)
            except (Exception, CallTooLong) as exc:  # the class's own failure: this UAV flies on, from a fresh agent
                log.error("uav %d: agent %s: load_state_dict raised %s: %s; not resumed from %s, starting afresh",
                          o.uav, self.agent_name, type(exc).__name__, " ".join(str(exc).split()), o.checkpoint)
                return None
            self.api.rng.bit_generator.state = rng_state
            self.steps = steps
            self.resumed = True
            log.info("uav %d (agent %s) resumed from checkpoint %s at step %d", o.uav, self.agent_name,
                     o.checkpoint, self.steps)
        elif o.qtable:  # a run of `truav train --agent NAME`, checked by the command before it started us
            state = agent_start_states(o.qtable, self.agent_name, self.cfg.scenario.n_uavs, o.qtable_index)[o.uav]
            call_limited(self.api.limit_s, self.api.agent.load_state_dict, state)
            log.info("uav %d (agent %s) starts from the state trained in %s", o.uav, self.agent_name, o.qtable)
        return None

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.decision = self.api  # its beacon() is what _send_beacon sends

    def _warm_up(self) -> None:
        self.api.warm_up()  # else its first tick is late on a busy host (the kernels load at its first reward)

    def _failed(self, obs: schema.Obs, what: str, exc: BaseException) -> None:
        self.agent_errors += 1
        line = str(exc) if isinstance(exc, IllegalAction) else f"{what} {exc}" if isinstance(exc, CallTooLong) else \
            f"{what} raised {type(exc).__name__}: {' '.join(str(exc).split())}"
        if self.first_agent_error is None:
            self.first_agent_error = line
            log.error("uav %d, tick %d: agent %s: %s; this UAV hovers where its agent fails (errors counted in its "
                      "stats, only the first logged)", self.opts.uav, obs.tick, self.agent_name, line)

    def handle(self, obs: schema.Obs) -> None:
        o, d = self.opts, self.api
        self._send_beacon(obs)
        if o.debug_delay_s:
            self._stop.wait(o.debug_delay_s)
        self._take_beacons()
        beacons = self._lockstep_beacons(obs.tick) if o.lockstep else self._realtime_beacons_in_range(obs.tick)
        try:
            r = d.learn(obs, beacons)
        except (Exception, CallTooLong) as exc:
            self._failed(obs, "learn", exc)
            r = 0.0 if d.view is not None and d.episode == obs.episode and d.t > 0 else None
        if r is not None:
            self.steps += 1
            if o.checkpoint and checkpoint_due(self.steps, o.uav, self.n_uavs, o.checkpoint_every):
                self.checkpoint()
        if obs.done:
            if o.lockstep:  # the acknowledgement the world waits for before the next tick
                self.bus.publish(keys.uav_action(o.run, o.uav), d.acknowledge(obs))
            return
        try:
            action = d.act(obs)
        except (Exception, CallTooLong) as exc:
            self._failed(obs, "act", exc)
            action = d.hover(obs)
        self.bus.publish(keys.uav_action(o.run, o.uav), action)

    def checkpoint(self) -> None:
        """Atomically write the agent's state_dict, its generator and the step count."""
        if not self.opts.checkpoint:
            return
        try:
            state = {STATE_PREFIX + k: np.asarray(v)
                     for k, v in call_limited(self.api.limit_s, self.api.agent.state_dict).items()}
        except (Exception, CallTooLong) as exc:
            log.error("uav %d: agent %s: state_dict raised %s: %s; no checkpoint written", self.opts.uav,
                      self.agent_name, type(exc).__name__, exc)
            return
        path = Path(self.opts.checkpoint)
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez(tmp, steps=self.steps, rng_state=json.dumps(self.api.rng.bit_generator.state), **state)
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
        log.info("uav %d: checkpoint at step %d -> %s", self.opts.uav, self.steps, path)

    def scheme_stats(self) -> dict:
        return {"agent": self.agent_name, "agent_errors": self.agent_errors,
                "first_agent_error": self.first_agent_error}


__all__ = ["ApiAgentNode"]

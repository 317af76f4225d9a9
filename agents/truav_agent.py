"""TRUAV's own learner through the agent API (agents.api): the API proved by use.

Registered as ``truav`` (``truav train --agent truav``). One instance is one UAV's independent tabular
Q-learner: the same arithmetic an agent process runs (agents.agent_decision.TruavDecision: its state
encoder, reward, Q-update and exploration draws, from the generator the API hands it, which is the one
TRUAV's trainer gives that UAV). So, with ideal beacon links, training it gives the Q-tables and
metrics of ``truav train``, entry for entry (tests/swarm/test_agent_api.py). Channel-driven links
(``links.model = "channel"``) are not applied to an API class's views in the trainer, so there it is not
TRUAV's run; nor does it federate (``federated.every``).

Its batched form (:class:`TruavBatched`) is TRUAV's own controller: step by step it is the arithmetic
above for all UAVs at once, and it offers the API's whole-episode form (``run_episode``), TRUAV's fused
kernel (agents.fused), so ``truav train --agent truav`` trains as fast as ``truav train``; all three forms
end in the same state, array for array (tests/swarm/test_agent_api.py). The swarm runs the per-UAV form.

Its state_dict is the whole decision state: the Q-table (S, 16), the exploration generator and the
episode's exploration draws, epsilon, the step, the last state and action, the velocity, the density
map and the last count of vehicles in range: a swarm agent restarted from its checkpoint goes on
exactly where it stopped.
"""

from __future__ import annotations

import numpy as np

from agents.agent_decision import TruavDecision
from agents.api import BatchedAgents, BatchedViews, LocalView, UavAgent
from agents.controller import TruavController
from agents.qlearning import QLearners, geofence
from agents.reward import Reward
from agents.state import StateEncoder
from truav.config import Config
from truav.wire import schema
from world.draws import rng_from_words, rng_words
from world.env import LocalObs
from world.link_phy import IDEAL
from world.uavs import action_velocity

_SCALARS = {"episode": np.int64, "t": np.int64, "state": np.int64, "action": np.int64, "epsilon": np.float64,
            "prev_in_range": np.float64}


class TruavBatched(BatchedAgents):
    """TRUAV's learners of B seeds x U UAVs at once (see the module docstring): the API's batched form, and its
    whole-episode form through TRUAV's fused kernel. State: TruavAgent's names, each stacked to (B, U, ...)."""

    call_limit_s = 60.0
    """One whole episode of every seed is one call (the first may load the compiled kernels)."""
    draws_in_kernel = True
    """run_episode makes the world's per-episode draws in the kernel, as TRUAV's trainer does."""

    def __init__(self, cfg: Config, rngs: list[list[np.random.Generator]]):
        super().__init__(cfg, rngs)
        B, U = len(rngs), len(rngs[0])
        # ideal links, no federation: what the API trainer gives every class (and TruavAgent computes)
        self.ctl = TruavController(cfg.replace(federated={"every": 0}), list(range(B)),
                                   rngs=[g for row in rngs for g in row])
        self.ctl.links = IDEAL
        self.episode, self.t = -1, 0

    def begin_episode(self, episode: int, train: bool) -> None:
        self.training = self.ctl.train = train
        self.episode, self.t = episode, 0

    def run_episode(self, world, obs: LocalObs) -> np.ndarray:
        """The whole episode in TRUAV's fused kernel, from its first observations; the mean reward (B,)."""
        from agents.fused import run_episode
        self.ctl.begin_episode(self.episode, obs)
        run_episode(world, self.ctl)
        self.t = self.cfg.scenario.steps_per_episode
        return self.ctl.episode_stats()["reward"]

    @staticmethod
    def _obs(views: BatchedViews) -> LocalObs:
        return LocalObs(views.pos, views.vehicles_in_range, views.queued_packets, views.relayed, views.covered,
                        views.energy_j, views.densest_sector, views.exclusive)

    def act(self, views: BatchedViews) -> np.ndarray:
        if views.step == 0:
            self.ctl.begin_episode(self.episode, self._obs(views))
        self.t = views.step
        return self.ctl.act(views.step).astype(np.int64)

    def learn(self, views: BatchedViews, reward: np.ndarray, done: bool) -> None:
        # TRUAV's controller computes the same reward (eq. (1)) from the observation and every peer's position
        self.ctl.observe(self._obs(views), done)
        self.t = views.step

    def state_dict(self) -> dict[str, np.ndarray]:
        c, lr = self.ctl, self.ctl.learners
        B, U = c.state.shape
        action = np.asarray(c.action, np.int64)
        full = lambda v, kind: np.full((B, U), v, kind)  # noqa: E731
        return {"episode": full(self.episode, np.int64), "t": full(self.t, np.int64), "state": c.state.copy(),
                "action": action.copy(), "epsilon": full(lr.epsilon, np.float64),
                "prev_in_range": np.asarray(c.prev_in_range, np.float64).copy(), "q": lr.q.copy(),
                "rng": np.stack([rng_words(g) for g in lr.rngs]).reshape(B, U, -1),
                "velocity": action_velocity(action, self.cfg.scenario.uav_speed_mps).astype(np.float64),
                "explore_u": lr._explore_u.transpose(1, 2, 0).copy(),
                "random_a": lr._random_a.transpose(1, 2, 0).copy(), "density_map": c.maps.copy()}

    def load_state_dict(self, state) -> None:
        c, lr = self.ctl, self.ctl.learners
        q = np.asarray(state["q"], np.float64)
        if q.shape != lr.q.shape or not np.isfinite(q).all():
            raise ValueError(f"q must be {lr.q.shape} finite values (this run's seeds, UAVs and states), got {q.shape}")
        lr.q[...] = q
        lr.rngs = [rng_from_words(w) for w in np.asarray(state["rng"], np.uint64).reshape(q.shape[0] * q.shape[1], -1)]
        lr.epsilon = float(np.asarray(state["epsilon"]).flat[0])
        lr._explore_u = np.ascontiguousarray(np.asarray(state["explore_u"], np.float64).transpose(2, 0, 1))
        lr._random_a = np.ascontiguousarray(np.asarray(state["random_a"], np.int64).transpose(2, 0, 1))
        self.episode, self.t = int(np.asarray(state["episode"]).flat[0]), int(np.asarray(state["t"]).flat[0])
        c.state = np.asarray(state["state"], np.int64).copy()
        c.action = np.asarray(state["action"], np.int64).copy()
        c.maps = np.ascontiguousarray(np.asarray(state["density_map"], np.float64)).reshape(c.maps.shape).copy()
        c.prev_in_range = np.asarray(state["prev_in_range"], np.float64).copy()


class TruavAgent(UavAgent):
    """One UAV's TRUAV Q-learner (see the module docstring)."""

    call_limit_s = 5.0
    """A first call may compile the encoder's kernels (cached after)."""
    batched = TruavBatched

    def __init__(self, cfg: Config, uav: int, rng: np.random.Generator):
        super().__init__(cfg, uav, rng)
        encoder = StateEncoder(cfg)
        learners = QLearners(cfg.learner, encoder.n_states, [rng], 1, 1, fence=geofence(cfg))
        self.decision = TruavDecision(cfg, uav, learners, True, encoder, Reward(cfg))

    def begin_episode(self, episode: int, train: bool) -> None:
        self.decision.train = train  # read by the decision's first learn of the episode (act at step 0)

    def _obs(self, view: LocalView, done: bool) -> schema.Obs:
        return schema.Obs(uav=self.uav, tick=view.step, episode=view.episode, done=done, pos=view.pos,
                          vehicles_in_range=view.vehicles_in_range, queued_packets=view.queued_packets,
                          relayed=view.relayed, covered=view.covered, energy_j=view.energy_j,
                          speed_max=view.speed_max, densest_sector=view.densest_sector, exclusive=view.exclusive)

    @staticmethod
    def _peers(view: LocalView) -> tuple[np.ndarray, np.ndarray]:
        """The heard peers' positions (1, 1, P, 2), in id order as the view lists them, and their mask."""
        peers = np.array([b.pos for b in view.beacons], np.float64).reshape(1, 1, len(view.beacons), 2)
        return peers, np.ones((1, 1, len(view.beacons)), np.bool_)

    def act(self, view: LocalView) -> int:
        if view.step == 0:  # the episode's first observation: the decision starts its episode from it
            self.decision.learn(self._obs(view, False), *self._peers(view))
        return self.decision.act(self._obs(view, False)).action

    def learn(self, view: LocalView, reward: float, done: bool) -> None:
        # The decision computes the same reward (eq. (1)) from the observation and the heard peers.
        self.decision.learn(self._obs(view, done), *self._peers(view))

    def state_dict(self) -> dict[str, np.ndarray]:
        d, lr = self.decision, self.decision.learners
        state = {name: np.array(getattr(lr if name == "epsilon" else d, name), kind)
                 for name, kind in _SCALARS.items()}
        state.update(q=lr.q[0, 0].copy(), rng=rng_words(lr.rngs[0]), velocity=np.array(d.velocity, np.float64),
                     explore_u=lr._explore_u[:, 0, 0].copy(), random_a=lr._random_a[:, 0, 0].copy(),
                     density_map=d.density_map[0, 0].copy())
        return state

    def load_state_dict(self, state: dict[str, np.ndarray]) -> None:
        d, lr = self.decision, self.decision.learners
        q = np.asarray(state["q"], np.float64)
        if q.shape != lr.q.shape[2:] or not np.isfinite(q).all():
            raise ValueError(f"q must be {lr.q.shape[2:]} finite values (this run's state space), got {q.shape}")
        lr.q[0, 0] = q
        lr.rngs[0] = self.rng = rng_from_words(np.asarray(state["rng"], np.uint64))
        lr.epsilon = float(state["epsilon"])
        steps = np.asarray(state["explore_u"]).shape[0]
        lr._explore_u = np.asarray(state["explore_u"], np.float64).reshape(steps, 1, 1).copy()
        lr._random_a = np.asarray(state["random_a"], np.int64).reshape(steps, 1, 1).copy()
        d.episode, d.t = int(state["episode"]), int(state["t"])
        d.state, d.action = int(state["state"]), int(state["action"])
        d._encoded = np.array([[d.state]], np.int64)
        d.velocity = tuple(float(v) for v in np.asarray(state["velocity"]))
        d.density_map[0, 0] = np.asarray(state["density_map"], np.float64)
        d.prev_in_range = float(state["prev_in_range"])


__all__ = ["TruavAgent", "TruavBatched"]

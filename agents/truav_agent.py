"""TRUAV's own learner through the agent API (agents.api): the API proved by use.

Registered as ``truav`` (``truav train --agent truav``). One instance is one UAV's independent tabular
Q-learner: the same arithmetic an agent process runs (agents.agent_decision.TruavDecision: its state
encoder, reward, Q-update and exploration draws, from the generator the API hands it, which is the one
TRUAV's trainer gives that UAV). So, with ideal beacon links, training it gives the Q-tables and
metrics of ``truav train``, entry for entry (tests/swarm/test_agent_api.py). It is the per-UAV form
only: the trainer steps it one call per UAV and step, far slower than TRUAV's fused kernels; use
``truav train`` (no --agent) for TRUAV itself. Channel-driven links (``links.model = "channel"``) are
not applied to an API class's views in the trainer, so there it is not TRUAV's run.

Its state_dict is the whole decision state: the Q-table (S, 16), the exploration generator and the
episode's exploration draws, epsilon, the step, the last state and action, the velocity, the density
map and the last count of vehicles in range: a swarm agent restarted from its checkpoint goes on
exactly where it stopped.
"""

from __future__ import annotations

import numpy as np

from agents.agent_decision import TruavDecision
from agents.api import LocalView, UavAgent
from agents.qlearning import QLearners, geofence
from agents.reward import Reward
from agents.state import StateEncoder
from truav.config import Config
from truav.wire import schema
from world.draws import rng_from_words, rng_words

_SCALARS = {"episode": np.int64, "t": np.int64, "state": np.int64, "action": np.int64, "epsilon": np.float64,
            "prev_in_range": np.float64}


class TruavAgent(UavAgent):
    """One UAV's TRUAV Q-learner (see the module docstring)."""

    call_limit_s = 5.0
    """A first call may compile the encoder's kernels (cached after)."""

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


__all__ = ["TruavAgent"]

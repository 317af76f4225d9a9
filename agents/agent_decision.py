"""One TRUAV agent's cycle over wire messages, without the bus: beacon, state, learn, act.

An agent process (agents.process.agent_process.AgentNode) runs it for its UAV and publishes what it returns; the
re-simulation of a recording (recorder.resim) runs one per UAV in process and compares what they return with
what was recorded. So a re-simulated beacon or action is what the process would have sent, field for field:
one algorithm, two drivers (and the trainer's arithmetic: StateEncoder, Reward, QLearners with B = U = 1).
"""

from __future__ import annotations

import numpy as np

from agents.prediction import new_maps, predict_batch, predict_params
from agents.qlearning import QLearners
from agents.reward import Reward
from agents.state import StateEncoder, neighbour_features
from truav.config import Config
from truav.wire import schema
from world.link_phy import beacon_delivered, link_params, link_probability, link_uniform
from world.uavs import action_velocity

DONE_ACK_ACTION = 0
"""The action field of a lock-step `done` observation's answer, an acknowledgement: the world ignores it."""


def peer_arrays(beacons: dict[int, schema.Beacon]) -> tuple[np.ndarray, np.ndarray]:
    """Neighbour positions (1, 1, P, 2) from beacons, in UAV-id order (as the trainer sums them), and their
    heard mask (all True)."""
    ids = sorted(beacons)
    peers = np.array([[[beacons[j].pos for j in ids]]], dtype=np.float64).reshape(1, 1, len(ids), 2)
    return peers, np.ones((1, 1, len(ids)), dtype=np.bool_)


class TruavDecision:
    """The decision state of one agent: the episode, its step, the last state and action, its velocity."""

    def __init__(self, cfg: Config, uav: int, learners: QLearners | None, train: bool = True,
                 encoder: StateEncoder | None = None, reward: Reward | None = None,
                 density_map: np.ndarray | None = None, seed: int = 0):
        self.cfg, self.uav, self.learners, self.train = cfg, uav, learners, train
        self.seed = seed
        """The run's seed: the channel-driven links' draws (world.link_phy), as the trainer's env of this seed."""
        self.links = link_params(cfg)
        self.link_counts: dict[int, list[float]] = {}
        """Channel-driven links: per peer, [beacons heard, beacons the channel lost, the model's expected heard
        count (sum of P_deliver), its variance (sum of P (1 - P))] (links.model "channel")."""
        self.share_counts: dict[int, list[int]] = {}
        """Channel-driven links, federated TRUAV: per peer, [shares heard, shares the channel lost]."""
        self._positions: tuple[tuple[float, float], dict[int, tuple[float, float]]] | None = None
        """This UAV's and its peers' positions at the last observation (a federated share's link)."""
        self.encoder = encoder if encoder is not None else StateEncoder(cfg)
        self.reward = reward if reward is not None else Reward(cfg)
        self.predict = predict_params(cfg)
        self.density_map = density_map if density_map is not None else new_maps(self.predict, 1, 1)
        """This UAV's decayed density map (1, 1, cells...; agents/prediction.py; no cells when prediction is off),
        updated in place by each observation."""
        self.prev_in_range = 0.0
        """Vehicles in range at the last observation (the shaping's phi(s))."""
        self.episode = -1
        self.t = 0
        self.state = 0
        self.action = 0
        self.velocity = (0.0, 0.0)
        self._encoded = np.zeros((1, 1), np.int64)  # the state as the encoder returned it (act's input)
        self.touched: set[int] = set()
        """Q-table rows updated so far: a snapshot (agents.decision_state) carries only these."""

    def beacon(self, obs: schema.Obs) -> schema.Beacon:
        """This UAV's beacon for the tick of ``obs`` (its velocity: that of its last action)."""
        return schema.Beacon(uav=self.uav, tick=obs.tick, pos=obs.pos, vel=self.velocity)

    def hear(self, obs: schema.Obs, beacons: dict[int, schema.Beacon]) -> dict[int, schema.Beacon]:
        """The beacons of ``obs``'s tick that the channel delivers to this UAV (all of them with ideal links),
        decided as the trainer decides them: beacon k of the episode (0 at its first observation, else one
        more than the last step learned) from peer j, by distance, seed, episode, k and the two ids."""
        links = self.links
        if not links.table.size:
            return beacons
        k = 0 if obs.episode != self.episode else self.t + 1
        x, y = float(obs.pos[0]), float(obs.pos[1])
        self._positions = ((x, y), {j: (float(b.pos[0]), float(b.pos[1])) for j, b in beacons.items()})
        kept = {}
        for j, b in beacons.items():
            # beacon_delivered's two halves: the trainer's decision, and the probability for the counts
            p = link_probability(links.table, links.step_m, x, y, float(b.pos[0]), float(b.pos[1]))
            ok = link_uniform(self.seed, obs.episode, k, j, self.uav) < p
            c = self.link_counts.setdefault(j, [0, 0, 0.0, 0.0])
            c[0 if ok else 1] += 1
            c[2] += p
            c[3] += p * (1.0 - p)
            if ok:
                kept[j] = b
        return kept

    def hear_share(self, peer: int, episode: int) -> bool:
        """Whether peer's federated share after ``episode`` reaches this UAV: decided as the trainer does
        (agents.controller), as beacon T + 1 of the episode between the positions of its last observation."""
        links = self.links
        if not links.table.size:
            return True
        (x, y), peers = self._positions if self._positions is not None else ((0.0, 0.0), {})
        if peer not in peers:  # no position known (its beacon never came): nothing to decide the link by
            return False
        px, py = peers[peer]
        ok = beacon_delivered(links.table, links.step_m, x, y, px, py, self.seed, episode,
                              self.cfg.scenario.steps_per_episode + 1, peer, self.uav)
        self.share_counts.setdefault(peer, [0, 0])[0 if ok else 1] += 1
        return ok

    def learn(self, obs: schema.Obs, peers: np.ndarray, heard: np.ndarray) -> np.ndarray | None:
        """Encode the state of ``obs`` with the peers' positions; at an episode's first observation start
        the episode, else learn from the last step. The reward (1, 1), or None at an episode's start (no
        step was taken, nothing learned)."""
        pos = np.array([[obs.pos]], dtype=np.float64)
        in_range = np.array([[obs.vehicles_in_range]], dtype=np.float64)
        nearest, overlap = neighbour_features(pos, peers, heard, self.cfg.scenario.comm_range_m)
        predicted = predict_batch(self.density_map, pos, in_range, self.predict)
        state = self.encoder.encode(pos, np.array([[obs.vehicles_in_range]]), np.array([[obs.queued_packets]]),
                                    nearest, self.encoder.neighbour_sectors(pos, peers, heard),
                                    np.array([[obs.densest_sector]]), predicted)
        r = None
        if obs.episode != self.episode:
            self.episode, self.t = obs.episode, 0
            self.learners.begin_episode(obs.episode, self.cfg.scenario.steps_per_episode, greedy=not self.train)
        else:
            r = self.reward(np.array([[obs.relayed]]), np.array([[obs.covered]]),
                            np.array([[obs.energy_j]]), overlap, np.array([[obs.exclusive]]), in_range,
                            np.array([[self.prev_in_range]]))
            if self.train:
                self.touched.add(self.state)
                self.learners.update(np.array([[self.state]]), np.array([[self.action]]), r, state, False)
            self.t += 1
        self.state, self._encoded = int(state[0, 0]), state
        self.prev_in_range = float(obs.vehicles_in_range)
        return r

    def act(self, obs: schema.Obs) -> schema.Action:
        """The action for a (not `done`) observation already learned from."""
        T = self.cfg.scenario.steps_per_episode
        pos = np.array([[obs.pos]], dtype=np.float64)
        self.action = int(self.learners.act(self._encoded, min(self.t, T - 1), pos)[0, 0])
        self.velocity = tuple(action_velocity(np.array(self.action), obs.speed_max))
        return schema.Action(uav=self.uav, tick=obs.tick, action=self.action)

    def acknowledge(self, obs: schema.Obs) -> schema.Action:
        """Lock-step: the answer to a `done` observation (learned from; no action taken)."""
        return schema.Action(uav=self.uav, tick=obs.tick, action=DONE_ACK_ACTION)


__all__ = ["DONE_ACK_ACTION", "TruavDecision", "peer_arrays"]

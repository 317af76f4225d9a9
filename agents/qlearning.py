"""Independent tabular Q-learning, B environments x U agents at once.

Each (environment, UAV) pair owns its own table (S, 16) and its own
Generator; nothing is shared between agents. The same class drives the
in-process trainer (B x U agents) and one swarm agent process (1 x 1).

Exploration is epsilon-greedy; epsilon decays exponentially from
epsilon_start to epsilon_end over epsilon_decay_fraction of the episodes,
then stays. The per-step exploration draws of an episode are made up front
from each agent's generator (fixed shapes), so results do not depend on the
batch an agent is trained in.

Geofence (learner.geofence, on in the `paper` preset): an agent never picks an
action whose full move would leave the area (it knows its own position and the area it may fly in). Without it, a
move into the border is clipped, the UAV hovers there at lower energy cost,
its state never changes, and a greedy policy whose argmax points into the
border is trapped for good (docs/results/reproduction.md, "The greedy collapse").
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from truav import kernel_cache  # noqa: F401, I001 - numba's cache set up before numba loads a kernel
from numba import njit

from truav.config import Config, LearnerConfig
from world.uavs import ACTION_UNIT_VELOCITY, N_ACTIONS


class Fence(NamedTuple):
    """The area an agent may fly in and how far an action moves it."""

    area: float
    """Side of the square area (m)."""
    reach: float
    """Full-speed move per step (m); 0 disables the fence."""
    unit: np.ndarray
    """(16+1, 2) action velocities per unit speed (world.uavs.ACTION_UNIT_VELOCITY)."""


NO_FENCE = Fence(np.inf, 0.0, ACTION_UNIT_VELOCITY)


def geofence(cfg: Config) -> Fence:
    """The fence of the scenario's area at its UAV speed, or none unless learner.geofence is on."""
    if not cfg.learner.geofence:
        return NO_FENCE
    sc = cfg.scenario
    return Fence(float(sc.area_m), float(sc.uav_speed_mps * sc.step_s), ACTION_UNIT_VELOCITY)


def epsilon_at(episode: int, lc: LearnerConfig) -> float:
    """Exploration rate of an episode."""
    horizon = max(lc.epsilon_decay_fraction * lc.episodes, 1.0)
    if episode >= horizon:
        return lc.epsilon_end
    if lc.epsilon_end <= 0.0 or lc.epsilon_start <= 0.0:
        return lc.epsilon_start + (lc.epsilon_end - lc.epsilon_start) * episode / horizon
    return float(lc.epsilon_start * (lc.epsilon_end / lc.epsilon_start) ** (episode / horizon))


class QLearners:
    """Tables q (B, U, S, 16) and per-agent generators (B*U of them, row-major)."""

    def __init__(self, lc: LearnerConfig, n_states: int, rngs: list[np.random.Generator],
                 batch: int, n_agents: int, q: np.ndarray | None = None, fence: Fence = NO_FENCE):
        if len(rngs) != batch * n_agents:
            raise ValueError(f"need {batch * n_agents} generators, got {len(rngs)}")
        self.lc = lc
        self.batch, self.n_agents, self.n_states = batch, n_agents, n_states
        self.rngs = list(rngs)
        if q is None:  # each agent's table drawn in place: no stacked copy of B x U tables
            q = np.empty((batch * n_agents, n_states, N_ACTIONS))
            for table, rng in zip(q, self.rngs):
                rng.random(out=table)
                table *= lc.q_init_scale
        self.q = np.ascontiguousarray(q, dtype=np.float64).reshape(batch, n_agents, n_states, N_ACTIONS)
        self.fence = fence
        self.epsilon = lc.epsilon_start
        self._explore_u = np.zeros((0, batch, n_agents))
        self._random_a = np.zeros((0, batch, n_agents), np.int64)

    def begin_episode(self, episode: int, steps: int, greedy: bool = False) -> None:
        """Set epsilon for the episode and draw its exploration randomness."""
        self.epsilon = 0.0 if greedy else epsilon_at(episode, self.lc)
        u = [rng.random(steps) for rng in self.rngs]
        a = [rng.integers(0, N_ACTIONS, steps) for rng in self.rngs]
        shape = (steps, self.batch, self.n_agents)
        self._explore_u = np.stack(u, axis=1).reshape(shape)
        self._random_a = np.stack(a, axis=1).reshape(shape)

    def greedy(self, states: np.ndarray, pos: np.ndarray | None = None) -> np.ndarray:
        """argmax_a Q(s, a) over the actions the fence allows at pos (B, U, 2), (B, U)."""
        return self.act(states, 0, pos, epsilon=0.0)

    def act(self, states: np.ndarray, t: int, pos: np.ndarray | None = None,
            epsilon: float | None = None) -> np.ndarray:
        """Epsilon-greedy actions (B, U) for step t of the episode, within the
        fence at the agents' positions pos (B, U, 2) (required with a fence)."""
        if pos is None:
            if self.fence.reach > 0.0:
                raise ValueError("a fenced learner needs the agents' positions")
            pos = np.zeros(states.shape + (2,))
        eps = self.epsilon if epsilon is None else epsilon
        return _act(self.q, states, self._explore_u[t] if len(self._explore_u) else np.ones(states.shape),
                    self._random_a[t] if len(self._random_a) else np.zeros(states.shape, np.int64), eps,
                    np.ascontiguousarray(pos, dtype=np.float64), self.fence)

    def update(self, s: np.ndarray, a: np.ndarray, r: np.ndarray, s_next: np.ndarray,
               terminal: bool) -> None:
        """One Q-learning update per agent: Q(s,a) += lr (r + g max Q(s',.) - Q(s,a)).
        `terminal` drops the bootstrap; episode ends are time limits of a
        continuing task, so drivers pass False there (Pardo et al., ICML 2018)."""
        _update(self.q, s, a, np.asarray(r, np.float64), s_next, bool(terminal),
                self.lc.learning_rate, self.lc.discount)


def states_visited(q: np.ndarray, lc: LearnerConfig, rngs: list[np.random.Generator]) -> np.ndarray:
    """States (B, U) whose row of q (B, U, S, 16) differs from its initial
    values, i.e. states the agent updated in at least once; rngs are fresh
    copies of the agents' generators (row-major), redrawing the initial tables
    one at a time as QLearners does."""
    batch, n_agents, n_states, n_actions = q.shape
    out = np.zeros(batch * n_agents, np.int64)
    init = np.empty((n_states, n_actions))
    for k, (table, rng) in enumerate(zip(q.reshape(batch * n_agents, n_states, n_actions), rngs)):
        rng.random(out=init)
        init *= lc.q_init_scale
        out[k] = int(np.count_nonzero((table != init).any(axis=1)))
    return out.reshape(batch, n_agents)


@njit(cache=True)
def allowed_one(a, x, y, fence):
    """Whether action a's full move from (x, y) stays inside the fenced area."""
    if fence.reach <= 0.0:
        return True
    nx = x + fence.unit[a, 0] * fence.reach
    ny = y + fence.unit[a, 1] * fence.reach
    tol = 1e-9 * fence.area
    return -tol <= nx <= fence.area + tol and -tol <= ny <= fence.area + tol


@njit(cache=True)
def act_one(q_row, explore_u, random_a, epsilon, x, y, fence):
    """One agent's epsilon-greedy action from its row Q(s, .), the step's
    draws and its position (x, y): the argmax over allowed actions (first on
    ties, as np.argmax), or when exploring the drawn action, the next allowed
    one (cyclically) if it would leave the area."""
    n = q_row.size
    if explore_u < epsilon:
        for k in range(n):
            a = (random_a + k) % n
            if allowed_one(a, x, y, fence):
                return a
    best, best_q = -1, -np.inf
    for a in range(n):
        if (best < 0 or q_row[a] > best_q) and allowed_one(a, x, y, fence):
            best, best_q = a, q_row[a]
    return best


@njit(cache=True)
def q_update_one(q, s, a, r, s_next, terminal, lr, discount):
    """One agent's update of its table q (S, 16): Q(s,a) += lr (r + g max Q(s',.) - Q(s,a))."""
    target = r
    if not terminal:
        target += discount * np.max(q[s_next])
    q[s, a] += lr * (target - q[s, a])


@njit(cache=True)
def fenced_actions(actions, pos, fence):
    """actions (B, U) with each one whose full move from pos (B, U, 2) would
    leave the area replaced by the next allowed action (cyclically): a fence
    outside the learner (an autopilot's), for the centralized baseline."""
    n = fence.unit.shape[0] - 1
    out = actions.copy()
    for b in range(actions.shape[0]):
        for u in range(actions.shape[1]):
            for k in range(n):
                a = (actions[b, u] + k) % n
                if allowed_one(a, pos[b, u, 0], pos[b, u, 1], fence):
                    out[b, u] = a
                    break
    return out


# The batch kernels below and the fused trainer (agents/fused.py) run the
# per-agent functions above, so a swarm agent (B = U = 1) learns by the same code.
@njit(cache=True)
def _act(q, states, explore_u, random_a, epsilon, pos, fence):
    n_env, n_agent = states.shape
    out = np.empty((n_env, n_agent), np.int64)
    for b in range(n_env):
        for u in range(n_agent):
            out[b, u] = act_one(q[b, u, states[b, u]], explore_u[b, u], random_a[b, u], epsilon,
                                pos[b, u, 0], pos[b, u, 1], fence)
    return out


@njit(cache=True)
def _update(q, s, a, r, s_next, terminal, lr, discount):
    for b in range(s.shape[0]):
        for u in range(s.shape[1]):
            q_update_one(q[b, u], s[b, u], a[b, u], r[b, u], s_next[b, u], terminal, lr, discount)

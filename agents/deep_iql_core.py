"""The deep independent learner's learning core (agents.deep_iql): DQN per network, N networks at once.

Each network learns alone from its own replay buffer: epsilon-greedy on its online network (the
episode's exploration draws made up front from its generator, as TRUAV's learners do, so a network's
draws do not depend on how many networks share the core), a transition stored per step, and every
``train_every`` stored transitions one Adam step on a minibatch drawn uniformly from its buffer,
towards r + discount x max over the next state's allowed actions of the target network (copied from
the online network every ``target_every`` updates), the TD error clipped (the Huber loss's gradient).

All counters move in lock-step over the N networks (they take the same calls), so they are kept once
and given to each network's state_dict. ``state()``/``load()`` hold everything a resume needs.
"""

from __future__ import annotations

import numpy as np

from agents.api import HOVER, N_ACTIONS
from agents.deep_iql_net import QNets, epsilon_at, first_allowed, greedy, rng_words, set_rng_words

_COUNTERS = ("transitions", "updates", "filled", "cursor", "adam_t", "episode", "acted")
_PER_NET = ("params", "target", "adam_m", "adam_v", "replay_x", "replay_a", "replay_r", "replay_x2",
            "replay_done", "replay_allowed2", "explore_u", "random_a", "last_x", "last_a")


class IqlCore:
    """N independent DQN learners on features of size n_features (see the module docstring)."""

    def __init__(self, hp, n_features: int, lc, steps: int, rngs: list[np.random.Generator]):
        self.hp, self.lc, self.rngs, self.steps = hp, lc, rngs, steps
        n, cap = len(rngs), hp.replay_capacity
        self.nets = QNets((n_features, *hp.hidden, N_ACTIONS), rngs)
        self.params = self.nets.params
        self.target = self.params.copy()
        self.adam_m, self.adam_v = np.zeros_like(self.params), np.zeros_like(self.params)
        # Features are stored as float32 (half the memory of a large buffer); act rounds its input the
        # same way, so a network acts and learns on the same values.
        self.replay_x = np.zeros((n, cap, n_features), np.float32)
        self.replay_x2 = np.zeros((n, cap, n_features), np.float32)
        self.replay_a = np.zeros((n, cap), np.int64)
        self.replay_r = np.zeros((n, cap))
        self.replay_done = np.zeros((n, cap), np.bool_)
        self.replay_allowed2 = np.zeros((n, cap, N_ACTIONS), np.bool_)
        self.explore_u = np.ones((n, steps))
        self.random_a = np.zeros((n, steps), np.int64)
        self.last_x = np.zeros((n, n_features), np.float32)
        self.last_a = np.full(n, HOVER, np.int64)
        self.transitions = self.updates = self.filled = self.cursor = self.adam_t = self.episode = 0
        self.acted = 0  # 1 once this episode's first act ran: a learn before it has no transition
        self.training, self.epsilon = True, 0.0

    def begin_episode(self, episode: int, train: bool) -> None:
        self.training, self.episode = train, episode
        self.acted = 0
        if not train:
            self.epsilon = 0.0
            return
        lc = self.lc
        self.epsilon = epsilon_at(episode, lc.epsilon_start, lc.epsilon_end, lc.epsilon_decay_fraction, lc.episodes)
        for i, rng in enumerate(self.rngs):
            self.explore_u[i] = rng.random(self.steps)
            self.random_a[i] = rng.integers(N_ACTIONS, size=self.steps)

    def act(self, x: np.ndarray, allowed: np.ndarray, step: int) -> np.ndarray:
        """Actions (N,) for features x (N, F) and the allowed actions (N, 16) at this step."""
        x = x.astype(np.float32)
        q, _ = self.nets.forward(self.params, x.astype(np.float64)[:, None, :])
        a = greedy(q[:, 0, :], allowed)
        if self.training and self.epsilon > 0.0:
            t = min(step, self.steps - 1)
            explore = self.explore_u[:, t] < self.epsilon
            a = np.where(explore, first_allowed(self.random_a[:, t], allowed), a)
        self.last_x[:], self.last_a[:], self.acted = x, a, 1
        return a

    def learn(self, x2: np.ndarray, allowed2: np.ndarray, reward: np.ndarray, done: bool) -> None:
        """Store the last step's transition (features x2 (N, F) after it, reward (N,)) and learn."""
        if not self.training or not self.acted:
            return  # evaluating, or no action taken in this episode yet
        c = self.cursor
        self.replay_x[:, c], self.replay_a[:, c], self.replay_r[:, c] = self.last_x, self.last_a, reward
        self.replay_x2[:, c], self.replay_done[:, c], self.replay_allowed2[:, c] = x2, done, allowed2
        self.cursor = (c + 1) % self.hp.replay_capacity
        self.filled = min(self.filled + 1, self.hp.replay_capacity)
        self.transitions += 1
        if self.transitions >= self.hp.warmup and self.transitions % self.hp.train_every == 0:
            self._update()

    def _update(self) -> None:
        hp, m = self.hp, self.hp.batch_size
        u = np.stack([rng.random(m) for rng in self.rngs])  # each network's minibatch from its generator
        idx = np.minimum((u * self.filled).astype(np.int64), self.filled - 1)
        rows = np.arange(len(self.rngs))[:, None]
        x, x2 = self.replay_x[rows, idx].astype(np.float64), self.replay_x2[rows, idx].astype(np.float64)
        a, r, done, ok2 = self.replay_a[rows, idx], self.replay_r[rows, idx], self.replay_done[rows, idx], \
            self.replay_allowed2[rows, idx]
        q, inputs = self.nets.forward(self.params, x)
        q2, _ = self.nets.forward(self.target, x2)
        best = np.where(ok2, q2, -np.inf).max(axis=-1)
        best = np.where(done | ~ok2.any(axis=-1), 0.0, best)
        y = r + self.lc.discount * best
        col = np.maximum(a, 0)[..., None]  # a HOVER (no allowed action) is stored but teaches nothing
        qa = np.take_along_axis(q, col, axis=-1)[..., 0]
        err = np.where(a >= 0, np.clip(qa - y, -hp.td_clip, hp.td_clip) / m, 0.0)
        dout = np.zeros_like(q)
        np.put_along_axis(dout, col, err[..., None], axis=-1)
        g = self.nets.backward(self.params, inputs, dout)
        self.adam_t += 1
        self.adam_m *= hp.adam_beta1
        self.adam_m += (1.0 - hp.adam_beta1) * g
        self.adam_v *= hp.adam_beta2
        self.adam_v += (1.0 - hp.adam_beta2) * (g * g)
        step = hp.learning_rate * np.sqrt(1.0 - hp.adam_beta2 ** self.adam_t) / (1.0 - hp.adam_beta1 ** self.adam_t)
        self.params -= step * self.adam_m / (np.sqrt(self.adam_v) + hp.adam_eps)
        self.updates += 1
        if self.updates % hp.target_every == 0:
            self.target[:] = self.params

    # -- state ---------------------------------------------------------------------------------
    def state(self) -> dict[str, np.ndarray]:
        """Per-network arrays (N, ...): parameters, target, Adam, replay, draws, counters, generators."""
        n = len(self.rngs)
        out = {k: getattr(self, k).copy() for k in _PER_NET}
        out.update({k: np.full(n, getattr(self, k), np.int64) for k in _COUNTERS})
        out["epsilon"] = np.full(n, self.epsilon)
        out["training"] = np.full(n, self.training)
        out["rng"] = np.stack([rng_words(rng) for rng in self.rngs])
        return out

    def load(self, state) -> None:
        """Restore what state() returned (shapes checked: a state of another size says so)."""
        for k in _PER_NET:
            have, want = np.asarray(state[k]), getattr(self, k)
            if have.shape != want.shape:
                raise ValueError(f"state {k!r} is shaped {have.shape[1:]}, this agent's {want.shape[1:]} "
                                 f"(other hyper-parameters or scenario?)")
            want[...] = have
        for k in _COUNTERS + ("epsilon", "training"):
            v = np.asarray(state[k]).ravel()
            if not (v == v[0]).all():
                raise ValueError(f"state {k!r} differs between the networks of one core: {v}")
            setattr(self, k, type(getattr(self, k))(v[0]))
        for rng, words in zip(self.rngs, np.asarray(state["rng"])):
            set_rng_words(rng, words)

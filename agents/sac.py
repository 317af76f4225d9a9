"""Discrete soft actor-critic for a swarm's joint action, batched over seeds.

One model per seed, all seeds of a batch held together: every parameter has a
leading seed axis and layers are batched matrix products, so B seeds train in
one set of tensor operations and seed b's numbers never mix with seed c's
(losses are summed over seeds, Adam is element-wise).

The networks (Haarnoja et al. 2018; discrete actions after Christodoulou
2019, "Soft Actor-Critic for Discrete Action Settings"):

- actor pi(s): joint state s (U x d, the concatenated per-UAV states) ->
  logits (U, 16); the joint policy factorises over UAVs, pi(a|s) = prod_i
  pi_i(a_i|s), so one forward pass gives the swarm's joint action;
- twin critics Q1, Q2 (s) -> (U, 16): Q_i(s, a_i), each UAV's soft value of
  its own action given the global state, trained on that UAV's reward;
- target critics (Polyak averaged) and a temperature alpha per seed, tuned to
  a target entropy per UAV.

Randomness: weights, replay sampling and action sampling all come from each
seed's numpy Generator, so a seed gives the same numbers whatever batch it is
trained in. torch is an optional dependency (the `central` extra) imported
only when a model is built.
"""

from __future__ import annotations

import math

import numpy as np

from truav.config import CentralConfig

_TORCH = None


def torch_module():
    """Import torch (the `central` extra), once, on one thread per process."""
    global _TORCH
    if _TORCH is None:
        try:
            import torch
        except ImportError as exc:  # pragma: no cover - depends on the install
            raise ImportError("the centralized baseline needs PyTorch: pip install -e '.[central]'") from exc
        torch.set_num_threads(1)  # one worker process per core
        _TORCH = torch
    return _TORCH


def _linear(rngs, fan_in, fan_out, copies=1):
    """(B*copies, fan_in, fan_out) weights and (B*copies, 1, fan_out) biases,
    U(-1/sqrt(fan_in), 1/sqrt(fan_in)) as torch.nn.Linear, from each seed's rng."""
    bound = 1.0 / math.sqrt(fan_in)
    w = [rng.uniform(-bound, bound, (fan_in, fan_out)) for rng in rngs for _ in range(copies)]
    b = [rng.uniform(-bound, bound, (1, fan_out)) for rng in rngs for _ in range(copies)]
    return np.stack(w).astype(np.float32), np.stack(b).astype(np.float32)


class _FusedAdam:
    """torch.optim.Adam(fused=True)'s step called directly: the same fused
    kernel on the same state (float32 step counters, zero moments), without
    the optimizer's per-step Python, which is about a third of a small
    update's time. Default betas and eps, no weight decay, as the optimizer."""

    def __init__(self, params, lr: float, betas=(0.9, 0.999), eps: float = 1e-8):
        torch = _TORCH
        self.params, self.lr, self.betas, self.eps = list(params), float(lr), betas, eps
        self.exp_avg = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.params]
        self.exp_avg_sq = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.params]
        self.steps = [torch.zeros((), dtype=torch.float32) for _ in self.params]

    def zero_grad(self) -> None:
        for p in self.params:
            p.grad = None

    def step(self) -> None:
        torch = _TORCH
        torch._foreach_add_(self.steps, 1)
        torch._fused_adam_(self.params, [p.grad for p in self.params], self.exp_avg, self.exp_avg_sq, [],
                           self.steps, amsgrad=False, lr=self.lr, beta1=self.betas[0], beta2=self.betas[1],
                           weight_decay=0.0, eps=self.eps, maximize=False, grad_scale=None, found_inf=None)


class BatchedSAC:
    """B independent discrete-SAC learners for U-agent joint actions."""

    def __init__(self, cfg: CentralConfig, discount: float, obs_dim: int, n_agents: int, n_actions: int,
                 rngs: list[np.random.Generator]):
        torch = torch_module()
        self.torch, self.cfg, self.discount = torch, cfg, float(discount)
        self.B, self.obs_dim, self.U, self.A = len(rngs), obs_dim, n_agents, n_actions
        self.rngs = rngs
        h = cfg.hidden
        sizes = [(obs_dim, h), (h, h), (h, n_agents * n_actions)]
        t = lambda x: torch.tensor(x, requires_grad=True)  # noqa: E731
        self.actor = [t(a) for fi, fo in sizes for a in _linear(rngs, fi, fo)]
        self.critic = [t(a) for fi, fo in sizes for a in _linear(rngs, fi, fo, copies=2)]  # (2B, ...)
        self.target = [p.detach().clone() for p in self.critic]
        self.log_alpha = torch.full((self.B,), math.log(cfg.init_alpha), requires_grad=True)
        self.target_entropy = cfg.target_entropy_scale * math.log(n_actions)
        adam = _FusedAdam  # element-wise: seeds stay apart
        self.actor_opt = adam(self.actor, cfg.actor_lr)
        self.critic_opt = adam(self.critic, cfg.critic_lr)
        self.alpha_opt = adam([self.log_alpha], cfg.critic_lr)
        cap = cfg.buffer_size
        self.obs = torch.zeros((self.B, cap, obs_dim))
        self.next_obs = torch.zeros((self.B, cap, obs_dim))
        self.actions = torch.zeros((self.B, cap, n_agents), dtype=torch.int64)
        self.rew = torch.zeros((self.B, cap, n_agents))
        self.size, self.ptr, self.updates = 0, 0, 0
        self._bidx = torch.arange(self.B)[:, None]

    # -- networks ---------------------------------------------------------------
    @staticmethod
    def _mlp(params, x):
        torch = _TORCH
        w1, b1, w2, b2, w3, b3 = params
        x = torch.relu(torch.baddbmm(b1, x, w1))
        x = torch.relu(torch.baddbmm(b2, x, w2))
        return torch.baddbmm(b3, x, w3)

    def _policy(self, s):
        """Log-probabilities and probabilities (B, M, U, A) for states (B, M, D)."""
        logits = self._mlp(self.actor, s).reshape(s.shape[0], s.shape[1], self.U, self.A)
        logp = self.torch.log_softmax(logits, dim=-1)
        return logp, logp.exp()

    def _q(self, params, s):
        """Twin critics (2, B, M, U, A) for states (B, M, D)."""
        x = s.repeat_interleave(2, dim=0)
        q = self._mlp(params, x).reshape(self.B, 2, s.shape[1], self.U, self.A)
        return q.transpose(0, 1)

    @property
    def alpha(self) -> np.ndarray:
        return self.log_alpha.detach().exp().numpy().astype(np.float64)

    # -- acting -----------------------------------------------------------------
    def act(self, state: np.ndarray, greedy: bool) -> np.ndarray:
        """Joint actions (B, U) for joint states (B, D): sampled from pi (each
        seed's rng) or its mode."""
        torch = self.torch
        with torch.no_grad():
            _, p = self._policy(torch.as_tensor(state, dtype=torch.float32)[:, None, :])
        p = p[:, 0].numpy().astype(np.float64)  # (B, U, A)
        if greedy:
            return p.argmax(axis=-1)
        u = np.stack([rng.random(self.U) for rng in self.rngs])[..., None]  # (B, U, 1)
        cdf = np.cumsum(p, axis=-1)
        return np.minimum((cdf < u * cdf[..., -1:]).sum(axis=-1), self.A - 1)

    def random_actions(self) -> np.ndarray:
        return np.stack([rng.integers(0, self.A, self.U) for rng in self.rngs])

    # -- learning ---------------------------------------------------------------
    def store(self, s, a, r, s_next) -> None:
        """One transition per seed: s, s_next (B, D); a (B, U) ints; r (B, U)."""
        torch, i = self.torch, self.ptr
        self.obs[:, i] = torch.as_tensor(s, dtype=torch.float32)
        self.next_obs[:, i] = torch.as_tensor(s_next, dtype=torch.float32)
        self.actions[:, i] = torch.as_tensor(a, dtype=torch.int64)
        self.rew[:, i] = torch.as_tensor(r, dtype=torch.float32)
        self.ptr = (i + 1) % self.cfg.buffer_size
        self.size = min(self.size + 1, self.cfg.buffer_size)

    def update(self) -> None:
        """One gradient step of critics, actor and temperature for every seed."""
        torch, cfg = self.torch, self.cfg
        if self.size == 0:
            return
        idx = torch.as_tensor(np.stack([rng.integers(0, self.size, cfg.batch_size) for rng in self.rngs]))
        s, s2 = self.obs[self._bidx, idx], self.next_obs[self._bidx, idx]
        a, r = self.actions[self._bidx, idx], self.rew[self._bidx, idx]  # (B, M, U)
        alpha = self.log_alpha.detach().exp()[:, None, None, None]
        with torch.no_grad():
            logp2, p2 = self._policy(s2)
            q2 = torch.min(*self._q(self.target, s2))  # (B, M, U, A)
            v2 = (p2 * (q2 - alpha * logp2)).sum(-1)
            y = r + self.discount * v2  # episode ends are time limits: always bootstrap
        q = self._q(self.critic, s).gather(-1, a[None, ..., None].expand(2, -1, -1, -1, 1))[..., 0]
        critic_loss = ((q - y[None]) ** 2).mean(dim=(2, 3)).sum()  # mean per seed, summed over seeds
        self.critic_opt.zero_grad()
        critic_loss.backward()
        self.critic_opt.step()

        logp, p = self._policy(s)
        with torch.no_grad():
            qmin = torch.min(*self._q(self.critic, s))
        actor_loss = (p * (alpha * logp - qmin)).sum(-1).mean(dim=(1, 2)).sum()
        self.actor_opt.zero_grad()
        actor_loss.backward()
        self.actor_opt.step()

        entropy = -(p.detach() * logp.detach()).sum(-1).mean(dim=(1, 2))  # (B,)
        alpha_loss = (self.log_alpha * (entropy - self.target_entropy)).sum()
        self.alpha_opt.zero_grad()
        alpha_loss.backward()
        self.alpha_opt.step()

        with torch.no_grad():  # Polyak averaging, one foreach call per operation
            torch._foreach_mul_(self.target, 1.0 - cfg.tau)
            torch._foreach_add_(self.target, [p_.detach() for p_ in self.critic], alpha=cfg.tau)
        self.updates += 1

    # -- state ------------------------------------------------------------------
    def state_dict(self) -> dict[str, np.ndarray]:
        """Every network as numpy arrays (seed axis first)."""
        out = {f"actor{i}": p.detach().numpy().copy() for i, p in enumerate(self.actor)}
        out.update({f"critic{i}": p.detach().numpy().copy() for i, p in enumerate(self.critic)})
        out["log_alpha"] = self.log_alpha.detach().numpy().copy()
        return out

    def load_actor(self, params: dict[str, np.ndarray]) -> None:
        with self.torch.no_grad():
            for i, p in enumerate(self.actor):
                p.copy_(self.torch.as_tensor(params[f"actor{i}"]))

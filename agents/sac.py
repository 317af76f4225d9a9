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

Speed (one thread per process; a gradient step of 10 seeds is about 1 ms of
matrix products): gradients are written out (agents.batched_mlp: autograd's
numbers without its graph), activations, gradients and the sampled batch live
in buffers allocated once, the replay is one preallocated row per transition
(a batch is one gather), and acting runs under inference_mode.
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
    update's time; the gradients are passed in (no autograd: .grad is unused).
    Default betas and eps, no weight decay, as the optimizer."""

    def __init__(self, params, lr: float, betas=(0.9, 0.999), eps: float = 1e-8):
        torch = _TORCH
        self.params, self.lr, self.betas, self.eps = list(params), float(lr), betas, eps
        self.exp_avg = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.params]
        self.exp_avg_sq = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.params]
        self.steps = [torch.zeros((), dtype=torch.float32) for _ in self.params]

    def step(self, grads) -> None:
        """One Adam step of the parameters along grads (tensors in the parameters' order)."""
        torch = _TORCH
        torch._foreach_add_(self.steps, 1)
        torch._fused_adam_(self.params, grads, self.exp_avg, self.exp_avg_sq, [],
                           self.steps, amsgrad=False, lr=self.lr, beta1=self.betas[0], beta2=self.betas[1],
                           weight_decay=0.0, eps=self.eps, maximize=False, grad_scale=None, found_inf=None)


class BatchedSAC:
    """B independent discrete-SAC learners for U-agent joint actions."""

    def __init__(self, cfg: CentralConfig, discount: float, obs_dim: int, n_agents: int, n_actions: int,
                 rngs: list[np.random.Generator]):
        torch = torch_module()
        from agents.batched_mlp import BatchedMlp
        self.torch, self.cfg, self.discount = torch, cfg, float(discount)
        self.B, self.obs_dim, self.U, self.A = len(rngs), obs_dim, n_agents, n_actions
        self.rngs = rngs
        h = cfg.hidden
        sizes = [(obs_dim, h), (h, h), (h, n_agents * n_actions)]
        self.actor = [torch.tensor(a) for fi, fo in sizes for a in _linear(rngs, fi, fo)]
        self.critic = [torch.tensor(a) for fi, fo in sizes for a in _linear(rngs, fi, fo, copies=2)]  # (2B, ...)
        self.target = [p.clone() for p in self.critic]
        self.log_alpha = torch.full((self.B,), math.log(cfg.init_alpha))
        self.target_entropy = cfg.target_entropy_scale * math.log(n_actions)
        adam = _FusedAdam  # element-wise: seeds stay apart
        self.actor_opt = adam(self.actor, cfg.actor_lr)
        self.critic_opt = adam(self.critic, cfg.critic_lr)
        self.alpha_opt = adam([self.log_alpha], cfg.critic_lr)
        # Replay: one float32 row per transition, s | s' | r | a (actions exact as floats below 2**24), seed b's
        # rows at b * capacity; zeros from calloc, so memory is taken as the replay fills.
        cap, D, U, M = cfg.buffer_size, obs_dim, n_agents, cfg.batch_size
        self._replay = torch.from_numpy(np.zeros((self.B * cap, 2 * D + 2 * U), np.float32))
        self._first_row = np.arange(self.B) * cap
        self.size, self.ptr, self.updates = 0, 0, 0
        # A sampled batch, and each network's activations and gradients, in buffers reused by every update.
        self._batch = torch.empty((self.B, M, 2 * D + 2 * U))
        self._s, self._s2 = torch.empty((self.B, M, D)), torch.empty((self.B, M, D))
        self._x, self._x2 = torch.empty((2 * self.B, M, D)), torch.empty((2 * self.B, M, D))  # one copy per critic
        self._grad_q = torch.zeros((self.B, 2, M, U, n_actions))  # zero but where an update scatters (and resets)
        self._actor_net = BatchedMlp(torch, self.actor, M)
        self._critic_net = BatchedMlp(torch, self.critic, M)
        # d(mean over the batch's M x U terms)/d(term), as autograd computes it (1 / (M U) in float32).
        self._mean_grad = float(torch.ones(()).expand(self.B).div(M * U)[0])

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
        return self.log_alpha.exp().numpy().astype(np.float64)

    # -- acting -----------------------------------------------------------------
    def act(self, state: np.ndarray, greedy: bool) -> np.ndarray:
        """Joint actions (B, U) for joint states (B, D): sampled from pi (each
        seed's rng) or its mode."""
        torch = self.torch
        with torch.inference_mode():
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
        self._replay.numpy()[self._first_row + self.ptr] = np.concatenate([s, s_next, r, a], axis=1)
        self.ptr = (self.ptr + 1) % self.cfg.buffer_size
        self.size = min(self.size + 1, self.cfg.buffer_size)

    def _sample(self):
        """A batch per seed from its rng: s, s' (B, M, D), their copies for the
        twin critics (2B, M, D), r (B, M, U) and a (B, M, U) int64."""
        torch, B, M, D, U = self.torch, self.B, self.cfg.batch_size, self.obs_dim, self.U
        idx = np.stack([rng.integers(0, self.size, M) for rng in self.rngs])
        rows = torch.from_numpy((idx + self._first_row[:, None]).reshape(-1))
        batch = torch.index_select(self._replay, 0, rows, out=self._batch.view(B * M, -1)).view(B, M, -1)
        s, s2 = self._s.copy_(batch[..., :D]), self._s2.copy_(batch[..., D:2 * D])
        self._x.view(B, 2, M, D).copy_(batch[:, None, :, :D])
        self._x2.view(B, 2, M, D).copy_(batch[:, None, :, D:2 * D])
        return s, s2, self._x, self._x2, batch[..., 2 * D:2 * D + U], batch[..., 2 * D + U:].long()

    def _net_policy(self, s):
        """_policy on the actor's buffers (for a batch of cfg.batch_size states)."""
        logits = self._actor_net.forward(self.actor, s).view(self.B, s.shape[1], self.U, self.A)
        logp = self.torch.log_softmax(logits, dim=-1)
        return logp, logp.exp()

    def update(self) -> None:
        """One gradient step of critics, actor and temperature for every seed.

        The losses (their gradients are written out below, as autograd
        computes them; tests/test_sac_grad.py):
        critic  sum_b mean_{m,u} (Q_c(s, a) - y)^2 over both critics c, with
                y = r + discount * sum_a pi(a|s') (min_c Q'_c(s', a) - alpha log pi(a|s'));
        actor   sum_b mean_{m,u} sum_a pi(a|s) (alpha log pi(a|s) - min_c Q_c(s, a)),
                with the critics just updated;
        alpha   sum_b log_alpha_b (entropy_b - target entropy)."""
        torch, cfg = self.torch, self.cfg
        if self.size == 0:
            return
        B, M, U, A = self.B, cfg.batch_size, self.U, self.A
        s, s2, x, x2, r, a = self._sample()
        alpha = self.log_alpha.exp()[:, None, None, None]
        logp2, p2 = self._net_policy(s2)
        q2 = self._critic_net.forward(self.target, x2).view(B, 2, M, U, A)
        v2 = (p2 * (torch.min(q2[:, 0], q2[:, 1]) - alpha * logp2)).sum(-1)
        y = r + self.discount * v2  # episode ends are time limits: always bootstrap

        q_all = self._critic_net.forward(self.critic, x).view(B, 2, M, U, A)
        taken = a[:, None, :, :, None].expand(-1, 2, -1, -1, 1)
        q = q_all.gather(-1, taken)[..., 0]  # (B, 2, M, U)
        grad_q = (2.0 * (q - y[:, None])).mul_(self._mean_grad)
        grad_out = self._grad_q.scatter_add_(-1, taken, grad_q[..., None]).view(2 * B, M, U * A)
        self.critic_opt.step(self._critic_net.backward(self.critic, x, grad_out))
        self._grad_q.scatter_(-1, taken, 0.0)

        logp, p = self._net_policy(s)
        qn = self._critic_net.forward(self.critic, x).view(B, 2, M, U, A)  # the updated critics
        z = alpha * logp - torch.min(qn[:, 0], qn[:, 1])
        grad_logp = (z * self._mean_grad) * p + (p * self._mean_grad) * alpha  # through pi = exp(log pi), and direct
        grad_logits = torch._log_softmax_backward_data(grad_logp, logp, -1, torch.float32).view(B, M, U * A)
        self.actor_opt.step(self._actor_net.backward(self.actor, s, grad_logits))

        entropy = -(p * logp).sum(-1).mean(dim=(1, 2))  # (B,)
        self.alpha_opt.step([entropy - self.target_entropy])

        torch._foreach_mul_(self.target, 1.0 - cfg.tau)  # Polyak averaging, one foreach call per operation
        torch._foreach_add_(self.target, self.critic, alpha=cfg.tau)
        self.updates += 1

    # -- state ------------------------------------------------------------------
    def state_dict(self) -> dict[str, np.ndarray]:
        """Every network as numpy arrays (seed axis first)."""
        out = {f"actor{i}": p.numpy().copy() for i, p in enumerate(self.actor)}
        out.update({f"critic{i}": p.numpy().copy() for i, p in enumerate(self.critic)})
        out["log_alpha"] = self.log_alpha.numpy().copy()
        return out

    def load_actor(self, params: dict[str, np.ndarray]) -> None:
        with self.torch.no_grad():
            for i, p in enumerate(self.actor):
                p.copy_(self.torch.as_tensor(params[f"actor{i}"]))

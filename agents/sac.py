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
matrix products, ~2.8 ms with the bias copies, ReLUs and their backward as
they run): gradients are written out (agents.batched_mlp: autograd's numbers
without its graph); activations, gradients and the sampled batch live in
buffers allocated once; the replay is one preallocated row per transition;
the element-wise steps between the matrix products, the batch gather, the
replay store and the action sampling are numba kernels (agents.sac_kernels:
torch's float32 operations in torch's order, so the same numbers); acting is
a preallocated 1-row forward; Polyak averaging is one pass (an exact fma,
as torch's add with alpha). bench/bench_sac.py times it: with the literal
config, 10 seeds, 1.7-1.95x less time per learning episode than at 0cd7060
(before the written-out gradients) depending on the machine state, 1.26x
less than the previous round (README.md has the figures).
"""

from __future__ import annotations

import math

import numpy as np

from agents import sac_kernels
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
        self._steps = torch.zeros(len(self.params), dtype=torch.float32)
        self.steps = list(self._steps.unbind())  # one float32 step counter per parameter, views of _steps

    def step(self, grads) -> None:
        """One Adam step of the parameters along grads (tensors in the parameters' order)."""
        torch = _TORCH
        self._steps.add_(1)  # every counter at once (torch.optim.Adam: _foreach_add_(steps, 1))
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
        # A sampled batch, and each network's activations and gradients, in buffers reused by every update;
        # numpy views of them for the kernels of agents.sac_kernels.
        A = n_actions
        self._s, self._s2 = torch.empty((self.B, M, D)), torch.empty((self.B, M, D))
        self._x, self._x2 = torch.empty((2 * self.B, M, D)), torch.empty((2 * self.B, M, D))  # one copy per critic
        self._r, self._a = torch.empty((self.B, M, U)), torch.empty((self.B, M, U), dtype=torch.int64)
        self._grad_q = torch.zeros((self.B, 2, M, U, A))  # zero but where an update writes (and resets)
        self._logp, self._p = torch.empty((self.B, M, U, A)), torch.empty((self.B, M, U, A))
        self._terms, self._terms2 = torch.empty((self.B, M, U, A)), torch.empty((self.B, M, U, A))
        self._v2, self._y = torch.empty((self.B, M, U)), torch.empty((self.B, M, U))
        self._ent = torch.empty((self.B, M, U))
        self._np = {k: getattr(self, "_" + k).numpy() for k in
                    ("replay", "s", "s2", "x", "x2", "r", "a", "grad_q", "logp", "p", "terms", "terms2", "v2", "y")}
        self._actor_net = BatchedMlp(torch, self.actor, M)
        self._critic_net = BatchedMlp(torch, self.critic, M)
        # Acting: one row per seed.
        self._act_net = BatchedMlp(torch, self.actor, 1, backward=False)
        self._act_state = torch.empty((self.B, 1, D))
        self._act_logp, self._act_p = torch.empty((self.B, 1, U, A)), torch.empty((self.B, 1, U, A))
        self._act_u = np.empty((self.B, U))
        # d(mean over the batch's M x U terms)/d(term), as autograd computes it (1 / (M U) in float32).
        self._mean_grad = float(torch.ones(()).expand(self.B).div(M * U)[0])
        self._mean_grad32 = np.float32(self._mean_grad)
        # Polyak averaging in one pass per tensor where that is torch's arithmetic (sac_kernels.polyak), else torch's
        self._keep32, self._tau32 = np.float32(1.0 - cfg.tau), np.float32(cfg.tau)
        self._polyak = [(t.numpy().reshape(-1), c.numpy().reshape(-1)) for t, c in zip(self.target, self.critic)] \
            if sac_kernels.polyak_is_torchs(torch, 1.0 - cfg.tau, cfg.tau) else None
        self._discount32 = np.float32(self.discount)  # as torch rounds a Python scalar for a float32 tensor

    # -- networks ---------------------------------------------------------------
    # The plain torch forward, differentiable by autograd: the update runs on BatchedMlp's buffers instead,
    # and tests/unit/test_sac_grad.py checks it against autograd through these.
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
        self._act_state.numpy()[:, 0] = state  # float32, as torch.as_tensor(state, dtype=torch.float32)
        logits = self._act_net.forward(self.actor, self._act_state).view(self.B, 1, self.U, self.A)
        torch.exp(torch.log_softmax(logits, -1, out=self._act_logp), out=self._act_p)
        p = self._act_p.numpy()[:, 0].astype(np.float64)  # (B, U, A)
        if greedy:
            return p.argmax(axis=-1)
        for rng, u in zip(self.rngs, self._act_u):
            rng.random(out=u)
        out = np.empty((self.B, self.U), np.int64)
        sac_kernels.sample_actions(p, self._act_u, out)
        return out

    def random_actions(self) -> np.ndarray:
        return np.stack([rng.integers(0, self.A, self.U) for rng in self.rngs])

    # -- learning ---------------------------------------------------------------
    def store(self, s, a, r, s_next) -> None:
        """One transition per seed: s, s_next (B, D); a (B, U) ints; r (B, U)."""
        sac_kernels.store_rows(self._np["replay"], self._first_row + self.ptr, np.asarray(s, np.float64),
                               np.asarray(s_next, np.float64), np.asarray(r, np.float64), np.asarray(a, np.int64))
        self.ptr = (self.ptr + 1) % self.cfg.buffer_size
        self.size = min(self.size + 1, self.cfg.buffer_size)

    def _sample(self):
        """A batch per seed from its rng into the buffers: s, s' (B, M, D), their
        copies for the twin critics (2B, M, D), r (B, M, U) and a (B, M, U) int64."""
        idx = np.stack([rng.integers(0, self.size, self.cfg.batch_size) for rng in self.rngs])
        n = self._np
        sac_kernels.gather_batch(n["replay"], self._first_row, idx, n["s"], n["s2"], n["x"], n["x2"], n["r"], n["a"])
        return self._s, self._s2, self._x, self._x2, self._r, self._a

    def _net_policy(self, s):
        """Log-probabilities and probabilities (B, M, U, A), in their buffers, for
        states (B, M, D) (cfg.batch_size of them) on the actor's buffers."""
        logits = self._actor_net.forward(self.actor, s).view(self.B, s.shape[1], self.U, self.A)
        logp = self.torch.log_softmax(logits, -1, out=self._logp)
        return logp, self.torch.exp(logp, out=self._p)

    def update(self) -> None:
        """One gradient step of critics, actor and temperature for every seed.

        The losses (their gradients are written out below, as autograd
        computes them; tests/unit/test_sac_grad.py):
        critic  sum_b mean_{m,u} (Q_c(s, a) - y)^2 over both critics c, with
                y = r + discount * sum_a pi(a|s') (min_c Q'_c(s', a) - alpha log pi(a|s'));
        actor   sum_b mean_{m,u} sum_a pi(a|s) (alpha log pi(a|s) - min_c Q_c(s, a)),
                with the critics just updated;
        alpha   sum_b log_alpha_b (entropy_b - target entropy).
        The element-wise steps are agents.sac_kernels' (the same float32
        operations in the same order as the torch expressions they replace)."""
        torch, cfg, n, k = self.torch, self.cfg, self._np, sac_kernels
        if self.size == 0:
            return
        B, M, U, A = self.B, cfg.batch_size, self.U, self.A
        self._sample()
        alpha = self.log_alpha.exp()
        alpha_np = alpha.numpy()
        self._net_policy(self._s2)
        q2 = self._critic_net.forward(self.target, self._x2).view(B, 2, M, U, A)
        k.soft_value_terms(n["p"], n["logp"], q2.numpy(), alpha_np, n["terms"])
        torch.sum(self._terms, -1, out=self._v2)
        # y = r + discount * v2 (episode ends are time limits: always bootstrap); the critics' output gradient
        q_all = self._critic_net.forward(self.critic, self._x).view(B, 2, M, U, A)
        k.critic_output_grad(q_all.numpy(), n["a"], n["r"], n["v2"], self._discount32, self._mean_grad32,
                             n["y"], n["grad_q"])
        self.critic_opt.step(self._critic_net.backward(self.critic, self._x, self._grad_q.view(2 * B, M, U * A)))
        k.clear_taken(n["grad_q"], n["a"])
        # Polyak averaging toward the updated critics (which the rest of the update only reads), while they are in
        # cache
        if self._polyak is not None:
            for target, online in self._polyak:
                k.polyak(target, online, self._keep32, self._tau32)
        else:
            torch._foreach_mul_(self.target, 1.0 - cfg.tau)
            torch._foreach_add_(self.target, self.critic, alpha=cfg.tau)

        logp, p = self._net_policy(self._s)
        qn = self._critic_net.forward(self.critic, self._x).view(B, 2, M, U, A)  # the updated critics
        # through pi = exp(log pi), and direct; and the entropy's terms p log p
        k.actor_logp_grad(n["logp"], n["p"], qn.numpy(), alpha_np, self._mean_grad32, n["terms"], n["terms2"])
        grad_logits = torch._log_softmax_backward_data(self._terms, logp, -1, torch.float32).view(B, M, U * A)
        self.actor_opt.step(self._actor_net.backward(self.actor, self._s, grad_logits))

        entropy = -torch.sum(self._terms2, -1, out=self._ent).mean(dim=(1, 2))  # (B,)
        self.alpha_opt.step([entropy - self.target_entropy])

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

"""Training the learned policy `ppo` (agents/ppo_agent.py) with Stable-Baselines3 (the `marl` extra).

Independent PPO with shared parameters (IPPO) over truav.analysis.ppo_vec_env.TruavVecEnv: every UAV of every
training environment is one slot acting on its own observation; no central critic (the value network sees the
same local observation). Two stages (docs/results/learned-policy.md):

1. behaviour cloning of the heuristic `spread` (agents/spread_agent.py): its batched form flies the training
   environments, and the policy learns its actions from the same observations (cross-entropy), the value
   network the discounted returns of the local reward it earns;
2. PPO fine-tuning on the local reward (plus an optional shaped team term, TruavVecEnv's coverage_bonus).

``export`` writes the policy branch as numpy arrays (agents.ppo_policy). ``greedy_coverage`` measures a
policy greedy in a vector of held-out environments (for the search; the reported numbers fly agents.ppo_agent
through the agent API, docs/scripts/ppo_train.py). Every random number comes from ``seed``.
"""

from __future__ import annotations

import time
from typing import Callable

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.vec_env import VecEnv

from agents.ppo_policy import NumpyPolicy
from agents.spread_agent import SpreadBatched
from truav import seeding
from truav.analysis.ppo_vec_env import TruavVecEnv, to_slot_actions
from truav.config import Config


KINDS = ("serving", "chasing", "keeping", "wandering")
"""The heuristic's decision at a state (agents/spread_agent.py): serving its cluster, chasing a sensed goal,
keeping what is in range (hovering), wandering with nothing in range."""


def decision_kind(teacher: SpreadBatched, views) -> np.ndarray:
    """Each slot's KINDS index of the decision ``teacher`` just took (after its act on ``views``)."""
    serving, chasing = teacher.last[:, 3] > 0, teacher.goal[:, 0] >= 0
    in_range = np.asarray(views.vehicles_in_range).reshape(-1) > 0
    return np.where(serving, 0, np.where(chasing, 1, np.where(in_range, 2, 3)))


def teacher_data(env: TruavVecEnv, episodes: int, gamma: float,
                 flier: Callable[[np.ndarray], np.ndarray] | None = None,
                 kinds: list | None = None,
                 teacher_cls: type = SpreadBatched) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(observations (N, F), the heuristic's slot actions (N,), discounted returns (N,)) of ``episodes``
    episodes of every slot, the heuristic flying, or ``flier`` (observations -> slot actions; DAgger: the
    heuristic labels the states the learner visits); appends each step's decision kinds to ``kinds``.
    ``teacher_cls``: the heuristic's batched form (`spread`'s, or e.g. agents.claim_agent.ClaimBatched), or a
    privileged teacher (a class attribute ``privileged``: shown the world's vehicles, ``see(vehicle_xy)``, before
    each act; truav.analysis.privileged_teacher)."""
    B, U = env.B, env.U
    # with the claim features, the rule the environment runs beside the UAVs is the teacher (its state is the
    # features': a second instance, fresh at each call, would label from another climb heading)
    shadow = getattr(env, "shadow", None)
    shared = shadow is not None and teacher_cls is type(shadow)
    teacher = shadow if shared else teacher_cls(env.cfg, [[seeding.agent_rng(s, u) for u in range(U)]
                                                           for s in env.seeds])
    obs_l, act_l, rew_l = [], [], []
    obs = env.reset()
    for e in range(episodes):
        teacher.begin_episode(e, False)
        ep_obs, ep_act, ep_rew = [], [], []
        while True:
            if getattr(teacher, "privileged", False):  # a privileged teacher sees the whole world's vehicles
                teacher.see(env.world.vehicle_xy(), getattr(env, "shadow_actions", None))
            a = to_slot_actions(env.shadow_actions if shared else teacher.act(env.views)).reshape(-1)
            if kinds is not None:
                kinds.append(decision_kind(teacher, env.views))
            ep_obs.append(obs)
            ep_act.append(a)
            obs, r, done, _ = env.step(a if flier is None else flier(obs))
            ep_rew.append(r)
            if done[0]:
                break
        ret, g = np.zeros_like(np.stack(ep_rew)), np.zeros(env.num_envs, np.float32)
        for t in range(len(ep_rew) - 1, -1, -1):
            g = ep_rew[t] + gamma * g
            ret[t] = g
        obs_l += ep_obs
        act_l += ep_act
        rew_l.append(ret.reshape(-1))
    return np.concatenate(obs_l), np.concatenate(act_l), np.concatenate(rew_l)


def clone(model: PPO, obs: np.ndarray, actions: np.ndarray, returns: np.ndarray, epochs: int, seed: int,
          lr: float = 1e-3, batch: int = 1024, say: Callable[[str], None] = print) -> float:
    """Fit the policy to the teacher's actions and the value to its returns; returns the final action accuracy."""
    policy = model.policy
    opt = torch.optim.Adam(policy.parameters(), lr=lr)
    rng = np.random.default_rng(seed)
    o, a, g = torch.as_tensor(obs), torch.as_tensor(actions), torch.as_tensor(returns)
    n = len(o)
    acc = 0.0
    for epoch in range(epochs):
        order = torch.as_tensor(rng.permutation(n))
        for i in range(0, n, batch):
            idx = order[i: i + batch]
            dist = policy.get_distribution(o[idx])
            values = policy.predict_values(o[idx]).squeeze(-1)
            loss = -dist.log_prob(a[idx]).mean() + 0.5 * torch.nn.functional.mse_loss(values, g[idx])
            opt.zero_grad()
            loss.backward()
            opt.step()
        with torch.no_grad():
            pick = torch.as_tensor(rng.choice(n, min(n, 20000), replace=False))
            acc = float((policy.get_distribution(o[pick]).distribution.logits.argmax(-1) == a[pick]).float().mean())
        say(f"  clone epoch {epoch + 1}/{epochs}: loss {float(loss.detach()):.3f}, accuracy {acc:.3f}")
    return acc


def agreement(arrays: dict[str, np.ndarray], cfg: Config, seeds: list[int], episodes: int) -> dict[str, float]:
    """The share of the states the exported greedy policy visits where its action is the heuristic's: over
    all ("all") and per decision kind of the heuristic (KINDS; with each kind's share of the states)."""
    policy = NumpyPolicy(arrays)
    env = TruavVecEnv(cfg, seeds, policy.peers or 4, memory=policy.memory, claim=policy.claim, disc=policy.disc)
    kinds: list = []
    obs, labels, _ = teacher_data(env, episodes, 0.0, lambda o: to_slot_actions(policy.greedy(o)), kinds)
    same = to_slot_actions(policy.greedy(obs)) == labels
    kind = np.concatenate(kinds)
    out = {"all": float(same.mean())}
    for i, name in enumerate(KINDS):
        out[name] = float(same[kind == i].mean()) if (kind == i).any() else float("nan")
        out[f"{name}_share"] = float((kind == i).mean())
    return out


def export(model: PPO, cfg: Config, peers: int, memory: bool = False, claim: bool = False,
           disc: bool = False) -> dict[str, np.ndarray]:
    """The policy branch and action head of SB3's MlpPolicy as agents.ppo_policy's arrays."""
    linears = [m for m in model.policy.mlp_extractor.policy_net if isinstance(m, torch.nn.Linear)]
    linears.append(model.policy.action_net)
    out: dict[str, np.ndarray] = {}
    for i, lin in enumerate(linears):
        out[f"w{i}"] = lin.weight.detach().numpy().T.astype(np.float32).copy()
        out[f"b{i}"] = lin.bias.detach().numpy().astype(np.float32).copy()
    out.update(peers=np.array(peers), n_features=np.array(out["w0"].shape[0]),
               sense_sectors=np.array(cfg.learner.sense_sectors), speed_mps=np.array(cfg.scenario.uav_speed_mps),
               memory=np.array(int(memory)), claim=np.array(int(claim)), disc=np.array(int(disc)))
    return out


def greedy_coverage(arrays: dict[str, np.ndarray], cfg: Config, seeds: list[int], episodes: int,
                    peers: int) -> np.ndarray:
    """Each seed's mean coverage (%) over ``episodes`` greedy episodes of the exported policy, in a vector."""
    policy = NumpyPolicy(arrays)
    env = TruavVecEnv(cfg, seeds, peers, memory=policy.memory, claim=policy.claim, disc=policy.disc)
    obs, cov = env.reset(), []
    for _ in range(episodes):
        while True:
            obs, _, done, infos = env.step(to_slot_actions(policy.greedy(obs)))
            if done[0]:
                cov.append([infos[b * env.U]["episode_coverage"] for b in range(env.B)])
                break
    return np.mean(cov, axis=0)


def make_ppo(env: VecEnv, *, lr: float = 1e-4, n_steps: int = 100, ent_coef: float = 0.0, seed: int = 0,
             net: list[int] | None = None) -> PPO:
    """The PPO model ``train`` fine-tunes (MlpPolicy; ``net``: its hidden widths, None: two of 64), with an
    in-memory logger: without one, Stable-Baselines3 makes a ``SB3-<date>`` directory in the temporary
    directory at every ``learn``."""
    model = PPO("MlpPolicy", env, learning_rate=lr, n_steps=n_steps, batch_size=min(env.num_envs * n_steps, 2000),
                n_epochs=5, gamma=0.99, gae_lambda=0.95, ent_coef=ent_coef, seed=seed, verbose=0, device="cpu",
                policy_kwargs=None if net is None else {"net_arch": list(net)})
    model.set_logger(Logger(folder=None, output_formats=[]))
    return model


def train(cfg: Config, seeds: list[int], *, peers: int = 4, bc_episodes: int = 20, bc_epochs: int = 8,
          ppo_steps: int = 0, lr: float = 1e-4, n_steps: int = 100, ent_coef: float = 0.0,
          coverage_bonus: float = 0.0, dagger_rounds: int = 0, seed: int = 0, memory: bool = False,
          net: list[int] | None = None, say: Callable[[str], None] = print,
          teacher: type = SpreadBatched, claim: bool = False, disc: bool = False) -> tuple[PPO, dict]:
    """Clone the heuristic (``teacher``, its batched form), then PPO for ``ppo_steps`` slot-steps; returns the
    model and timings. ``net``: the hidden layers' widths of the policy and the value network (None: MlpPolicy's,
    two of 64). ``claim``: observe the climbing heuristic's features, ``disc`` the densest sensed disc's
    (agents.view_features; learner.sense_disc on in ``cfg``)."""
    torch.manual_seed(seed)
    env = TruavVecEnv(cfg, seeds, peers, coverage_bonus, memory, claim, disc)
    model = make_ppo(env, lr=lr, n_steps=n_steps, ent_coef=ent_coef, seed=seed, net=net)
    times = {}
    t0 = time.perf_counter()
    if bc_episodes:
        obs, act, ret = teacher_data(env, bc_episodes, model.gamma, teacher_cls=teacher)
        times["teacher_s"] = time.perf_counter() - t0
        say(f"  teacher: {len(obs)} samples in {times['teacher_s']:.0f} s")
        times["accuracy"] = clone(model, obs, act, ret, bc_epochs, seed, say=say)
        for r in range(dagger_rounds):  # the learner flies, the heuristic labels; trained on everything so far
            flier = NumpyPolicy(export(model, cfg, peers, memory, claim, disc)).greedy
            more = teacher_data(env, bc_episodes, model.gamma, lambda o: to_slot_actions(flier(o)),
                                teacher_cls=teacher)
            obs, act, ret = (np.concatenate([x, y]) for x, y in zip((obs, act, ret), more))
            say(f"  DAgger round {r + 1}/{dagger_rounds}: {len(obs)} samples")
            times["accuracy"] = clone(model, obs, act, ret, max(2, bc_epochs // 2), seed + r + 1, say=say)
    times["clone_s"] = time.perf_counter() - t0
    if ppo_steps:
        t1 = time.perf_counter()
        model.learn(total_timesteps=ppo_steps, reset_num_timesteps=True)
        times["ppo_s"] = time.perf_counter() - t1
    times["total_s"] = time.perf_counter() - t0
    return model, times


__all__ = ["KINDS", "agreement", "clone", "decision_kind", "export", "greedy_coverage", "make_ppo", "teacher_data",
           "train"]

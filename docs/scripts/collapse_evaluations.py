"""Greedy collapse under persist: train (keeping the world), then compare
evaluation variants on held-out traffic. Usage: diag2.py SEEDS EPISODES TAG [overrides]"""
import sys, time, numpy as np
from collapse_args import diag_setup
from truav import seeding
from agents.controller import TruavController
from world.env import World
from world.uavs import ACTION_UNIT_VELOCITY, N_ACTIONS

cfg, seeds, episodes, tag = diag_setup(sys.argv)
A, vdt = cfg.scenario.area_m, cfg.scenario.uav_speed_mps * cfg.scenario.step_s

def feasible(pos):  # (B,U,2) -> (B,U,16): the full move stays inside the area
    new = pos[..., None, :] + ACTION_UNIT_VELOCITY[None, None, :N_ACTIONS] * vdt
    return np.all((new >= 0) & (new <= A), axis=-1)

def run(c, world, n_ep, first_obs, mask=False, fallback=None, record=None):
    cov = []
    obs = first_obs
    for ep in range(n_ep):
        if ep:
            obs = world.start_episode()
        c.begin_episode(ep if c.train else 0, obs)
        done, t = False, 0
        while not done:
            a = c.act(t)
            if mask or fallback is not None:
                q = c.learners.q[np.arange(len(c.state))[:, None], np.arange(c.state.shape[1])[None], c.state]
                if mask:
                    q = np.where(feasible(world.uav_pos), q, -np.inf)
                a = q.argmax(-1)
                if fallback is not None:
                    unseen = ~fallback[np.arange(len(c.state))[:, None], np.arange(c.state.shape[1])[None], c.state]
                    rnd = rng.integers(0, N_ACTIONS, a.shape)
                    if mask:
                        ok = feasible(world.uav_pos)
                        rnd = np.array([[rng.choice(np.flatnonzero(ok[b, u])) for u in range(a.shape[1])] for b in range(a.shape[0])])
                    a = np.where(unseen, rnd, a)
            if record is not None:
                record.append(world.uav_pos.copy())
            obs, _, done = world.step(a)
            c.observe(obs, done); t += 1
        cov.append(world.episode_summary()["coverage_pct"])
    return np.array(cov)

rng = np.random.default_rng(123)
t0 = time.time()
ctrl = TruavController(cfg, seeds, train=True)
world = World(cfg, len(seeds))
obs = world.reset([seeding.world_rng(s) for s in seeds])
# count visits per (b,u,state) during training
visits = np.zeros(ctrl.learners.q.shape[:3], np.int64)
orig_observe = ctrl.observe
def observe(o, d):
    np.add.at(visits, (np.arange(len(seeds))[:, None], np.arange(cfg.scenario.n_uavs)[None], ctrl.state), 1)
    orig_observe(o, d)
ctrl.observe = observe
train_cov = run(ctrl, world, episodes, obs)
print(f"[{tag}] train {time.time()-t0:.0f}s; last 100 eps coverage per seed", train_cov[-100:].mean(0).round(1))
final_pos = world.uav_pos.copy()
q = ctrl.learners.q.copy()
seen = visits > 0
print("states visited per agent:", seen.sum(-1).ravel().tolist())
np.savez(f"runs/diag/d2_{tag}.npz", q=q, visits=visits, final_pos=final_pos, train_cov=train_cov)
ev = [s + 10000 for s in seeds]
def fresh(start=None):
    c = TruavController(cfg, ev, train=False, q=q.copy())
    w = World(cfg, len(ev)); o = w.reset([seeding.world_rng(s) for s in ev])
    if start is not None:
        w.uav_pos = start.copy(); o = w.start_episode()
    return c, w, o
for name, start, mask, fb in [("greedy, fresh random deployment", None, False, None),
                              ("greedy, swarm continues from training", final_pos, False, None),
                              ("greedy + wall mask, fresh", None, True, None),
                              ("greedy + wall mask + random in unvisited, fresh", None, True, seen),
                              ("greedy + wall mask, continues", final_pos, True, None)]:
    c, w, o = fresh(start)
    cov = run(c, w, 20, o, mask, fb)
    print(f"[{tag}] {name}: {cov.mean(0).round(1)} mean {cov.mean():.1f}", flush=True)

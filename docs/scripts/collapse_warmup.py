"""Continuing evaluation of saved persist Q-tables: where is the rest of the gap?"""
import json, os, sys, numpy as np
from truav.config import load_config
from truav import seeding
from agents.controller import TruavController
from world.env import World
from world.uavs import N_ACTIONS
os.makedirs("runs/diag", exist_ok=True)
tag = sys.argv[1]; extra = json.loads(sys.argv[2]) if len(sys.argv) > 2 else {}
d = np.load(f"runs/diag/d2_{tag}.npz"); q, visits, final_pos = d["q"], d["visits"], d["final_pos"]
B, U = q.shape[:2]
ov = {"scenario": {"uav_start": "persist", "uav_speed_mps": 15.0}, "learner": {"episodes": len(d["train_cov"])}}
for k, v in extra.items():
    ov.setdefault(k, {}).update(v)
cfg = load_config(None, ov)
seen = visits > 0
ev = [s + 10000 for s in range(B)]
rng = np.random.default_rng(5)
def go(name, eps=0.0, learn=False, fallback=False, seeds=ev, n=20):
    c = TruavController(cfg, seeds, train=False, q=q.copy()); c.train = learn
    w = World(cfg, B); o = w.reset([seeding.world_rng(s) for s in seeds]); w.uav_pos = final_pos.copy(); o = w.start_episode()
    cov, unseen_frac, stuck = [], [], []
    bi, ui = np.arange(B)[:, None], np.arange(U)[None]
    for ep in range(n):
        if ep: o = w.start_episode()
        c.begin_episode(0, o); c.learners.epsilon = eps
        if eps > 0:
            c.learners._explore_u = rng.random(c.learners._explore_u.shape)
        done, t, un = False, 0, []
        while not done:
            a = c.act(t)
            us = ~seen[bi, ui, c.state]
            if fallback:
                a = np.where(us, rng.integers(0, N_ACTIONS, a.shape), a)
            un.append(us)
            o, _, done = w.step(a); c.observe(o, done); t += 1
        cov.append(w.episode_summary()["coverage_pct"]); unseen_frac.append(np.mean(un))
    cov = np.array(cov)
    print(f"{name}: mean {cov.mean():.1f} per seed {cov.mean(0).round(1)}; by episode {cov.mean(1).round(0)}; unvisited-state steps {np.mean(unseen_frac):.3f}", flush=True)
print("train last 100:", d["train_cov"][-100:].mean(0).round(1))
go("greedy, continuing, held-out")
go("greedy, continuing, training seeds' traffic (fresh world)", seeds=list(range(B)))
go("eps 0.05, continuing, held-out", eps=0.05)
go("greedy + random in unvisited, continuing", fallback=True)
go("greedy, learning on, continuing", learn=True)

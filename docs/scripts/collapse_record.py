"""Diagnose the greedy collapse under uav_start=persist: train, then run greedily
while recording positions, states, actions; print stuck/self-loop stats; map."""
import json, os, sys, time, numpy as np
from agents.controller import TruavController
from truav import seeding
from truav.analysis.driver import run_episodes
from truav.config import load_config
from world.env import World

os.makedirs("runs/diag", exist_ok=True)
seeds = list(range(int(sys.argv[1]) if len(sys.argv) > 1 else 2))
episodes = int(sys.argv[2]) if len(sys.argv) > 2 else 1000
tag = sys.argv[3] if len(sys.argv) > 3 else "base"
extra = json.loads(sys.argv[4]) if len(sys.argv) > 4 else {}
ov = {"scenario": {"uav_start": "persist", "uav_speed_mps": 15.0}, "learner": {"episodes": episodes}}
for k, v in extra.items():
    ov.setdefault(k, {}).update(v)
cfg = load_config(None, ov)
t0 = time.time()
ctrl = TruavController(cfg, seeds, train=True)
m = run_episodes(cfg, seeds, ctrl, episodes)
print(f"train {time.time()-t0:.0f}s; last 100 eps coverage per seed", m["coverage_pct"][-100:].mean(0).round(1),
      "eps", m["epsilon"][-1])
q = ctrl.learners.q.copy()
np.save(f"runs/diag/q_{tag}.npy", q)

def evaluate(q, eval_seeds, n_ep=20, train=False):
    c = TruavController(cfg, eval_seeds, train=False, q=q.copy())
    c.train = train  # learn online, but act greedily (epsilon set to 0 below)
    world = World(cfg, len(eval_seeds))
    obs = world.reset([seeding.world_rng(s) for s in eval_seeds])
    cov, rec = [], {"pos": [], "state": [], "action": []}
    for ep in range(n_ep):
        if ep:
            obs = world.start_episode()
        c.begin_episode(ep, obs)
        c.learners.epsilon = 0.0
        done, t = False, 0
        while not done:
            a = c.act(t)
            rec["state"].append(c.state.copy()); rec["action"].append(a.copy()); rec["pos"].append(world.uav_pos.copy())
            obs, _, done = world.step(a)
            c.observe(obs, done); t += 1
        cov.append(world.episode_summary()["coverage_pct"])
    return np.array(cov), {k: np.array(v) for k, v in rec.items()}

ev_seeds = [s + 10000 for s in seeds]
cov, rec = evaluate(q, ev_seeds)
print("greedy eval coverage per seed", cov.mean(0).round(1), "per episode (mean seeds)", cov.mean(1).round(1))
pos, st, act = rec["pos"], rec["state"], rec["action"]  # (T, B, U, ...)
moved = np.linalg.norm(np.diff(pos, axis=0), axis=-1)  # (T-1,B,U)
A = cfg.scenario.area_m
at_wall = (pos[..., 0] <= 1e-6) | (pos[..., 0] >= A - 1e-6) | (pos[..., 1] <= 1e-6) | (pos[..., 1] >= A - 1e-6)
print(f"fraction of UAV-steps at the boundary: {at_wall.mean():.3f}; not moving (<1 m): {(moved < 1).mean():.3f}")
same_state = (st[1:] == st[:-1])
print(f"fraction of steps whose state equals the previous: {same_state.mean():.3f}")
# last-half positions: count per 500 m cell
fin = pos[-1].reshape(-1, 2)
print("final positions (x,y):", fin.round(0).tolist())
# distinct states visited in eval, per agent
nst = [len(np.unique(st[:, b, u])) for b in range(st.shape[1]) for u in range(st.shape[2])]
print("distinct states per agent in eval:", nst)
# training-time visit counts: how many states have Q differing from init? (any entry < 0 means updated since rewards mostly negative)
visited = (np.abs(q) > cfg.learner.q_init_scale).any(-1)
print("states with updated Q per agent:", visited.reshape(-1, visited.shape[-1]).sum(-1).tolist(), "of", q.shape[2])
# greedy action at states seen during eval: Q gap between best and second best
np.savez(f"runs/diag/eval_{tag}.npz", pos=pos, state=st, action=act, cov=cov)
# also: eval with online learning continuing (epsilon 0) for contrast
cov2, _ = evaluate(q, ev_seeds, train=True)
print("greedy but still updating Q (eps 0):", cov2.mean(0).round(1))

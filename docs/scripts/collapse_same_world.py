"""Train under persist, then continue the very same world (deep copies) under
several policies: separates the policy's greedy collapse from traffic/start effects."""
import copy, sys, time, numpy as np
from collapse_args import diag_setup
from truav import seeding
from agents.controller import TruavController
from world.env import World
cfg, seeds, episodes, tag = diag_setup(sys.argv)
def run(c, w, n, start_ep, eps=None, o=None):
    cov = []
    for ep in range(n):
        o = w.start_episode() if (ep or o is None) else o
        c.begin_episode(start_ep + ep, o)
        if eps is not None:
            c.learners.epsilon = eps
        done, t = False, 0
        while not done:
            o, _, done = w.step(c.act(t)); c.observe(o, done); t += 1
        cov.append(w.episode_summary()["coverage_pct"])
    return np.array(cov)
t0 = time.time()
ctrl = TruavController(cfg, seeds, train=True)
world = World(cfg, len(seeds)); o = world.reset([seeding.world_rng(s) for s in seeds])
tc = run(ctrl, world, episodes, 0, o=o)
print(f"[{tag}] train {time.time()-t0:.0f}s last 100: {tc[-100:].mean(0).round(1)} mean {tc[-100:].mean():.1f}", flush=True)
np.savez(f"runs/diag/d4_{tag}.npz", q=ctrl.learners.q, pos=world.uav_pos, train_cov=tc)
n = 50
for name, learn, eps in [("keep training (eps_end, learning)", True, None), ("greedy, frozen", False, 0.0),
                         ("eps_end, frozen", False, cfg.learner.epsilon_end), ("greedy, learning", True, 0.0)]:
    c = copy.deepcopy(ctrl); w = copy.deepcopy(world); c.train = learn
    cov = run(c, w, n, episodes, eps)
    print(f"[{tag}] same world, {name}: {cov.mean(0).round(1)} mean {cov.mean():.1f}; first 5 eps {cov[:5].mean(1).round(0)}", flush=True)

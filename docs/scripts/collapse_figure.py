"""docs/figures/greedy_collapse.png: where persist-trained agents have been
(training state visits per 500 m cell) vs where greedy UAVs go from a fresh deployment."""
import numpy as np, matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt
from truav.config import Config
d2 = np.load("runs/diag/d2_base.npz"); ev = np.load("runs/diag/eval_base.npz")
cfg = Config(); cells, per_cell = 10, 144
visits = d2["visits"]  # (B, U, S)
B, U, S = visits.shape
majors = np.array(cfg.roads.major_intersections) * cfg.roads.block_m
fig, axes = plt.subplots(1, 2, figsize=(11, 5.2))
for b, ax in zip([0], axes[:1]):
    grid = visits[b].reshape(U, cells * cells, per_cell).sum(-1).sum(0).reshape(cells, cells)  # [cx, cy]
    im = ax.imshow(np.log10(grid.T + 1), origin="lower", extent=(0, 5000, 0, 5000), cmap="Greys")
    plt.colorbar(im, ax=ax, label="log10(1 + training steps in cell), 5 agents")
    ax.scatter(*d2["final_pos"][b].T, marker="^", c="tab:blue", s=60, label="UAVs at the end of training")
    ax.set_title(f"training (persist, 1000 episodes), seed {b}:\nstates visited per agent "
                 f"{(visits[b] > 0).sum(-1).tolist()} of {S}", fontsize=9)
pos = ev["pos"]  # (T, B, U, 2) greedy eval from a fresh deployment, held-out traffic
ax = axes[1]
for u in range(U):
    ax.plot(pos[:, 0, u, 0], pos[:, 0, u, 1], lw=0.8)
    ax.scatter(*pos[0, 0, u], marker="o", c="k", s=20)
    ax.scatter(*pos[-1, 0, u], marker="x", c="r", s=60)
ax.set_title("greedy evaluation from a fresh random deployment, seed 0:\n"
             "20 episodes (o start, x end); 96% of steps in never-visited states", fontsize=9)
for a in axes:
    a.scatter(*majors.T, marker="s", facecolors="none", edgecolors="tab:orange", s=80, label="major intersections")
    a.set_xlim(0, 5000); a.set_ylim(0, 5000); a.set_aspect("equal"); a.set_xlabel("x (m)"); a.set_ylabel("y (m)")
axes[0].legend(fontsize=7, loc="upper right")
fig.tight_layout(); fig.savefig("docs/figures/greedy_collapse.png", dpi=110)

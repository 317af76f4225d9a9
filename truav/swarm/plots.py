"""The picture at the end of `truav-swarm up`: map with roads, RSUs, major
intersections, vehicles and UAV tracks, beside the coverage timeline."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from truav.config import Config, n_grid_roads  # noqa: E402
from world.network import rsu_positions  # noqa: E402


def draw_map(ax, cfg: Config) -> None:
    """Roads, RSUs and major intersections of the scenario on `ax`."""
    block, n = cfg.roads.block_m, n_grid_roads(cfg)
    extent = (n - 1) * block
    for k in range(n):
        ax.plot([0, extent], [k * block] * 2, color="0.88", lw=0.6, zorder=0)
        ax.plot([k * block] * 2, [0, extent], color="0.88", lw=0.6, zorder=0)
    majors = np.array(cfg.roads.major_intersections, float) * block
    ax.scatter(majors[:, 0], majors[:, 1], marker="s", s=40, facecolor="none", edgecolor="0.4",
               label="major intersection", zorder=2)
    rsu = rsu_positions(cfg)
    ax.scatter(rsu[:, 0], rsu[:, 1], marker="^", s=90, color="k", label="RSU", zorder=4)
    ax.set_xlim(-100, cfg.scenario.area_m + 100)
    ax.set_ylim(-100, cfg.scenario.area_m + 100)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")


def split_jumps(pts: np.ndarray, max_hop: float) -> np.ndarray:
    """Insert a NaN row where consecutive points are further apart than a UAV
    can fly (a new episode re-places the UAVs), so no fake flight is drawn."""
    if len(pts) < 2:
        return pts
    jump = np.flatnonzero(np.linalg.norm(np.diff(pts, axis=0), axis=1) > max_hop) + 1
    return np.insert(pts.astype(float), jump, np.nan, axis=0)


def swarm_figure(cfg: Config, monitor, path: Path, title: str = "swarm") -> Path:
    fig, (ax, tl) = plt.subplots(1, 2, figsize=(13, 6), gridspec_kw={"width_ratios": [1.1, 1]})
    draw_map(ax, cfg)
    with monitor.lock:
        tracks = {u: np.array(p) for u, p in monitor.tracks.items()}
        vehicles = np.array(monitor.vehicles)
        coverage = np.array(monitor.coverage)
        hovering = np.array(monitor.hovering)
    if vehicles.size:
        ax.scatter(vehicles[:, 0], vehicles[:, 1], s=4, color="C7", alpha=0.6, label="vehicles (last)", zorder=1)
    R = cfg.scenario.comm_range_m
    max_hop = 3.0 * cfg.scenario.uav_speed_mps * cfg.scenario.step_s
    for u, pts in sorted(tracks.items()):
        pts = split_jumps(pts, max_hop)
        color = f"C{u % 10}"
        ax.plot(pts[:, 0], pts[:, 1], color=color, lw=1.2, alpha=0.9, zorder=3)
        ax.add_patch(plt.Circle(pts[-1], R, color=color, alpha=0.12, zorder=1))
        ax.scatter(*pts[-1], color=color, s=30, zorder=5, label=f"UAV {u}")
    ax.legend(loc="upper left", fontsize=7, ncol=2, framealpha=0.8)
    ax.set_title("UAV tracks (from beacons), coverage discs at the end")
    if coverage.size:
        tl.plot(coverage[:, 0], coverage[:, 1], color="C0", lw=1, label="coverage (%)")
        tl.set_ylabel("coverage (%)")
        tl.set_xlabel("tick")
        tl.grid(alpha=0.3)
        if hovering.size and hovering[:, 1].any():
            ax2 = tl.twinx()
            ax2.bar(hovering[:, 0], hovering[:, 1], color="C3", alpha=0.5, width=1.0, label="missed actions")
            ax2.set_ylabel("UAVs without an action (hovered)")
    tl.set_title("coverage per tick")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path

"""The picture at the end of `truav-swarm up`: map with roads, RSUs, major
intersections, vehicles and UAV tracks, beside the coverage timeline (a fault
plan's windows shaded)."""

from __future__ import annotations

import math
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


MAX_LABELLED_UAVS = 20
"""Above this many UAVs a map draws thin tracks without ids or coverage discs (a hundred of them are clutter)."""


def fault_lanes(plan, end_s: float) -> list[tuple[str, float, float | None, bool]]:
    """(label, start, stop or None for an instant, lasts to the end of the run) per fault of a plan."""
    lanes = []
    for f in plan.faults:
        target = f.params.get("uav", f.params.get("target", f.params.get("keys", "")))
        label = f"{f.kind} {target}".strip()
        if f.kind == "crash":
            restart = f.params.get("restart_after")
            lanes.append((label, f.start, None if restart is None else f.start + float(restart), False))
        else:
            forever = math.isinf(f.duration)
            lanes.append((label, f.start, end_s if forever else min(f.end, end_s), forever))
    return lanes


def shade_faults(axes, plan, end_s: float, scale: float = 1.0) -> list:
    """Shade each fault's window (x in seconds since tick 0, times ``scale``) on every axis of
    ``axes``; a crash never restarted is shaded to the end. Returns legend handles, one per fault."""
    from matplotlib.patches import Patch
    handles = []
    for n, (label, start, stop, forever) in enumerate(fault_lanes(plan, end_s)):
        color = f"C{(2 + n) % 10}" if (2 + n) % 10 != 3 else "C9"  # C0 and C3 draw the data
        stop = end_s if stop is None else stop
        for ax in axes:
            ax.axvspan(start * scale, max(stop, start) * scale, color=color, alpha=0.15, lw=0, zorder=0)
        handles.append(Patch(color=color, alpha=0.3, label=f"{label}, {start:g}-"
                             + ("end" if forever or stop >= end_s else f"{stop:g}") + " s"))
    return handles


def uav_color(u: int, n: int):
    """tab10 up to 10 UAVs, tab20 above (no two UAVs share a colour up to 20)."""
    return plt.get_cmap("tab10" if n <= 10 else "tab20")(u % (10 if n <= 10 else 20))


def last_segment(pts: np.ndarray, max_hop: float) -> tuple[np.ndarray, int]:
    """The points after the last jump further than a UAV can fly (a new episode re-places
    the UAVs): the last episode's track; and how many segments there were."""
    if len(pts) < 2:
        return pts, 1
    jumps = np.flatnonzero(np.linalg.norm(np.diff(pts, axis=0), axis=1) > max_hop) + 1
    return pts[jumps[-1]:] if jumps.size else pts, jumps.size + 1


def episode_of(tick: int, steps: int) -> int:
    """The 0-based episode of a world tick: each episode is ``steps`` acting ticks and its done tick."""
    return tick // (steps + 1)


def tracks_title(last_tick: int, steps: int, finished: int) -> str:
    """What the map shows, counting only finished episodes as finished (an interrupted run's
    last episode is cut short)."""
    current = episode_of(last_tick, steps) + 1
    if current > finished:
        done = f"; {finished} finished" if finished else ""
        return f"UAV tracks in episode {current} (cut short{done})"
    if current > 1:
        return f"UAV tracks in the last episode ({current} of {current})"
    return "UAV tracks (from beacons)"


def no_miss_text(missed: int | None) -> str:
    """What the missed-actions panel says when the step metrics heard show no UAV without an action: only
    the world's own count can say that none was missed."""
    if missed == 0:
        return "every UAV acted in time on every tick"
    if missed is None:
        return "none in the step metrics heard\n(the world's own count is unknown)"
    return f"none in the step metrics heard, but the world\ncounted {missed} missed action(s), on ticks not heard"


def swarm_figure(cfg: Config, monitor, path: Path, title: str = "swarm", plan=None,
                 episodes_done: int | None = None, missed: int | None = None) -> Path:
    """``plan``: the run's fault plan (its windows shaded); ``episodes_done``: episodes the world
    finished (default: the episode summaries the monitor heard); ``missed``: the actions the world counted
    missing (its world.json), which the step metrics heard may not all show (an interrupted run)."""
    fig = plt.figure(figsize=(13, 6.8))
    grid = fig.add_gridspec(2, 2, width_ratios=[1.1, 1], height_ratios=[3, 1], hspace=0.08)
    ax = fig.add_subplot(grid[:, 0])
    tl = fig.add_subplot(grid[0, 1])
    miss_ax = fig.add_subplot(grid[1, 1], sharex=tl)
    draw_map(ax, cfg)
    with monitor.lock:
        tracks = {u: np.array(p) for u, p in monitor.tracks.items()}
        vehicles = np.array(monitor.vehicles)
        coverage = np.array(monitor.coverage)
        hovering = np.array(monitor.hovering)
        heard_done = len(monitor.episodes)
    if vehicles.size:
        ax.scatter(vehicles[:, 0], vehicles[:, 1], s=4, color="0.55", alpha=0.6, label="vehicles (at the end)",
                   zorder=1)
    R = cfg.scenario.comm_range_m
    max_hop = 3.0 * cfg.scenario.uav_speed_mps * cfg.scenario.step_s
    n_uavs = max(len(tracks), cfg.scenario.n_uavs)
    many = len(tracks) > MAX_LABELLED_UAVS
    for u, pts in sorted(tracks.items()):
        seg, _ = last_segment(pts, max_hop)
        color = uav_color(u, n_uavs)
        ax.plot(seg[:, 0], seg[:, 1], color=color, lw=0.6 if many else 1.4, alpha=0.7 if many else 0.95, zorder=3)
        if many:
            ax.scatter(*seg[-1], color=color, s=8, zorder=5)
            continue
        ax.add_patch(plt.Circle(seg[-1], R, color=color, alpha=0.10, zorder=1))
        ax.scatter(*seg[0], facecolor="white", edgecolor=color, s=22, lw=1.2, zorder=5)
        ax.scatter(*seg[-1], color=color, s=30, zorder=5)
        ax.annotate(str(u), seg[-1], xytext=(4, 4), textcoords="offset points", fontsize=8, color=color,
                    weight="bold", zorder=6)
    if many:
        ax.scatter([], [], color="k", s=8, label=f"UAV at the end ({len(tracks)} UAVs: no ids or coverage discs "
                                                   f"above {MAX_LABELLED_UAVS})")
    else:
        ax.scatter([], [], facecolor="white", edgecolor="k", s=22, label="UAV at the episode's start")
        ax.scatter([], [], color="k", s=30, label="UAV at the end (id), coverage disc")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.09), ncol=3, fontsize=7, framealpha=0.85)
    steps = cfg.scenario.steps_per_episode
    finished = heard_done if episodes_done is None else episodes_done
    ax.set_title(tracks_title(int(coverage[-1, 0]), steps, finished) if coverage.size else "UAV tracks (from beacons)")
    if coverage.size:
        tl.plot(coverage[:, 0], coverage[:, 1], color="C0", lw=1.1, zorder=3)
        tl.set_ylabel("coverage (%)")
        tl.set_ylim(0, max(5.0, float(np.nanmax(coverage[:, 1])) * 1.15))
        tl.grid(alpha=0.3)
        last_tick = int(coverage[-1, 0])
        per = steps + 1  # an episode's acting ticks and its done tick
        for k in range(1, episode_of(last_tick, steps) + 1):
            for a in (tl, miss_ax):
                a.axvline(k * per - 0.5, color="0.5", lw=0.8, ls=":", zorder=1)
        for k in range(0, episode_of(last_tick, steps) + 1):
            middle = (k * per + min(k * per + steps, last_tick)) / 2  # of what was flown (a cut episode: less)
            tl.text(middle, 1.0, f"ep {k + 1}", transform=tl.get_xaxis_transform(),
                    ha="center", va="bottom", fontsize=8, color="0.35")
    shaded = plan is not None and bool(plan.faults) and coverage.size > 0
    if shaded:
        rate = 1.0 / monitor.period_s
        handles = shade_faults((tl, miss_ax), plan, int(coverage[-1, 0]) / rate, scale=rate)
        tl.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=7, frameon=False,
                  title="fault windows", title_fontsize=7)
    plt.setp(tl.get_xticklabels(), visible=False)
    if hovering.size and hovering[:, 1].any():
        miss_ax.step(hovering[:, 0], hovering[:, 1], where="mid", color="C3", lw=1.0)
        miss_ax.set_ylim(0, max(1.0, float(hovering[:, 1].max())) * 1.2)
        miss_ax.yaxis.get_major_locator().set_params(integer=True)
    else:
        miss_ax.set_ylim(0, 1)
        miss_ax.set_yticks([])
        miss_ax.text(0.5, 0.5, no_miss_text(missed), transform=miss_ax.transAxes,
                     ha="center", va="center", fontsize=9, color="0.35")
    miss_ax.set_ylabel("UAVs without\nan action", fontsize=9)
    miss_ax.set_xlabel("tick")
    miss_ax.grid(alpha=0.3)
    tl.set_title("coverage per tick (episodes separated by dotted lines)", pad=14)
    fig.suptitle(title)
    fig.subplots_adjust(left=0.06, right=0.85 if shaded else 0.98,  # room for the fault windows' legend
                         top=0.89, bottom=0.14, wspace=0.18)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path

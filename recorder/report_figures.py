"""The figures of ``truav report``: map.png, metrics.png and agents.png from a :class:`Recording`.

Each ``*_figure(rec, path)`` draws with matplotlib (imported on first use,
Agg backend: files only) and returns a one-line description of what it drew,
or None when the recording has nothing to show (the figure is then skipped).
"""

from __future__ import annotations

import math
import textwrap
from pathlib import Path
from typing import Any, Optional

import numpy as np

from recorder.report_data import NS, FaultSpan, Recording, Series

DPI = 110
HEAT_BINS = 120  # heat map cells per axis
MAX_AGENT_ROWS = 60  # agents.png: above this many agents, no per-agent labels or boxes (height stays bounded)
MAX_METRIC_PANELS = 12
# step metrics as people read them, in the order they matter (others follow, by name)
METRIC_LABELS = {
    "coverage_pct": "coverage (% of vehicles)",
    "covered": "vehicles covered",
    "generated": "packets generated",
    "delivered": "packets delivered",
    "dropped": "packets dropped",
    "delay_sum_s": "relay delay, all packets (s)",
    "energy_j": "energy per UAV (J/step)",
    "hovering_uavs": "UAVs without an action",
    "rejected": "messages the world refused (total so far)",
}
UAV_COUNT_LABELS = {"missed": "actions missed (hovered)", "late": "actions too late", "stale": "actions out of order",
                    "rejected": "messages refused"}
"""The world's per-UAV counts (world.world_stats.UAV_METRIC_COUNTS), each a total so far."""


def metric_label(name: str) -> str:
    """A step metric's name as a reader says it: ``uav.2.missed`` is "UAV 2: actions missed (hovered), total
    so far", ``rejected.<reason>`` "messages the world refused as <reason>"."""
    if name in METRIC_LABELS:
        return METRIC_LABELS[name]
    head, _, rest = name.partition(".")
    if head == "uav":
        uav, _, count = rest.partition(".")
        if uav.isdigit() and count in UAV_COUNT_LABELS:
            return f"UAV {uav}: {UAV_COUNT_LABELS[count]}, total so far"
    if head == "rejected" and rest:
        return f"messages the world refused as {rest.replace('_', ' ')} (total so far)"
    return name.replace("_", " ")


TRACK_BREAK_MIN_M = 100.0  # a jump longer than this (and 5x the usual step) starts a new track segment
TRACK_BREAK_FACTOR = 5.0
DEFAULT_RANGE_M = 500.0  # coverage radius when the file holds no config (the paper's 500 m)
MIN_BIN_S = 1.0
TARGET_BINS = 300  # time bins for rates and latency timelines
MAP_MARGIN = 0.05
MAP_LEGEND_COLUMNS = 5
LOG_SCALE_SPREAD = 20.0  # latency axes go logarithmic when p99 exceeds this many medians
FAULT_COLORS = {"loss": "tab:red", "latency": "tab:orange", "partition": "tab:purple", "crash": "black",
                "freeze": "tab:cyan"}


# --- figures -------------------------------------------------------------------------------------
def _plt():
    import matplotlib

    matplotlib.use("Agg")  # files only
    import matplotlib.pyplot as plt

    return plt


def _bins(rec: Recording) -> np.ndarray:
    """Equal time bins spanning exactly the recording (no partial bin at the end to misread as a rate drop)."""
    if rec.duration_s <= 0:
        return np.array([0.0, MIN_BIN_S])
    n = max(1, round(rec.duration_s / max(MIN_BIN_S, rec.duration_s / TARGET_BINS)))
    return np.linspace(0.0, rec.duration_s, n + 1)


def _shade_faults(ax: Any, spans: list[FaultSpan], end_s: float, label: bool = False) -> None:
    seen: set[str] = set()
    for span in spans:
        color = FAULT_COLORS.get(span.fault, "tab:gray")
        text = f"fault: {span.fault}" if label and span.fault not in seen else None
        seen.add(span.fault)
        ax.axvspan(span.start_s, end_s if span.end_s is None else span.end_s, color=color, alpha=0.15, lw=0,
                   label=text)


def _extent(rec: Recording, tracks: dict[int, Series]) -> tuple[float, float, float, float]:
    if rec.config is not None:
        a = rec.config.area_m
        return (-MAP_MARGIN * a, a * (1 + MAP_MARGIN), -MAP_MARGIN * a, a * (1 + MAP_MARGIN))
    pts = [np.asarray(s.xy, dtype=float) for s in tracks.values() if s.xy] + [v for v in rec.vehicles if len(v)]
    if not pts:
        return (0.0, 1.0, 0.0, 1.0)
    allp = np.concatenate([p.reshape(-1, 2) for p in pts])
    allp = allp[np.isfinite(allp).all(axis=1)]
    if not len(allp):
        return (0.0, 1.0, 0.0, 1.0)
    (x0, y0), (x1, y1) = allp.min(axis=0), allp.max(axis=0)
    pad = max(x1 - x0, y1 - y0, 1.0) * MAP_MARGIN + DEFAULT_RANGE_M * 0.2
    return (x0 - pad, x1 + pad, y0 - pad, y1 + pad)


def _segments(xy: np.ndarray) -> list[np.ndarray]:
    """Split a track where it jumps (UAVs are re-placed at each episode start)."""
    ok = np.isfinite(xy).all(axis=1)
    xy = xy[ok]
    if len(xy) < 2:
        return [xy] if len(xy) else []
    steps = np.hypot(*np.diff(xy, axis=0).T)
    typical = np.median(steps[steps > 0]) if np.any(steps > 0) else 0.0
    breaks = np.nonzero(steps > max(TRACK_BREAK_MIN_M, TRACK_BREAK_FACTOR * typical))[0] + 1
    return [seg for seg in np.split(xy, breaks) if len(seg)]


def map_figure(rec: Recording, path: Path) -> Optional[str]:
    """Roads, RSUs, vehicle density, UAV tracks and coverage; None if nothing to draw."""
    source, tracks = rec.tracks()
    if not tracks and not rec.vehicles:
        return None
    plt = _plt()
    from matplotlib.collections import LineCollection
    from matplotlib.colors import LogNorm
    from matplotlib.lines import Line2D
    from matplotlib.patches import Circle

    x0, x1, y0, y1 = _extent(rec, tracks)
    fig, ax = plt.subplots(figsize=(9.5, 8.5))
    handles: list[Any] = []
    if rec.vehicles:  # density: mean vehicles per km^2 over the sampled positions messages
        pts = np.concatenate(rec.vehicles)
        hist, xe, ye = np.histogram2d(pts[:, 0], pts[:, 1], bins=HEAT_BINS, range=[[x0, x1], [y0, y1]])
        cell_km2 = (xe[1] - xe[0]) * (ye[1] - ye[0]) / 1e6
        density = hist.T / max(len(rec.vehicles), 1) / cell_km2
        density[density <= 0] = np.nan
        finite = density[np.isfinite(density)]
        if finite.size:
            im = ax.imshow(density, origin="lower", extent=(x0, x1, y0, y1), cmap="YlOrRd", alpha=0.85,
                           norm=LogNorm(vmin=max(finite.min(), finite.max() / 1e3), vmax=finite.max()),
                           interpolation="nearest", zorder=1)
            bar = fig.colorbar(im, ax=ax, shrink=0.7, pad=0.02)
            bar.set_label(f"vehicle density, vehicles/km² (mean of {len(rec.vehicles)} snapshots)")
    cfg = rec.config
    if cfg is not None:
        n = int(math.floor(cfg.area_m / cfg.block_m + 1e-9)) + 1
        for k in range(n):
            c = k * cfg.block_m
            ax.plot([c, c], [0, cfg.area_m], color="0.6", lw=0.5, zorder=0)
            ax.plot([0, cfg.area_m], [c, c], color="0.6", lw=0.5, zorder=0)
        handles.append(Line2D([], [], color="0.6", lw=0.8, label=f"roads ({cfg.block_m:g} m blocks)"))
        if cfg.majors:
            mx, my = zip(*cfg.majors)
            handles.append(ax.scatter(mx, my, marker="s", s=70, facecolor="none", edgecolor="0.25", lw=1.2,
                                      zorder=3, label="major intersection"))
        if cfg.rsus:
            rx, ry = zip(*cfg.rsus)
            handles.append(ax.scatter(rx, ry, marker="^", s=140, color="black", edgecolor="white", zorder=6,
                                      label="RSU"))
    radius = cfg.comm_range_m if cfg is not None else DEFAULT_RANGE_M
    cmap = plt.get_cmap("tab10" if len(tracks) <= 10 else "tab20")
    from truav.analysis.swarm_plots import MAX_LABELLED_UAVS
    many = len(tracks) > MAX_LABELLED_UAVS  # thin tracks, no discs, no per-UAV legend: a hundred of them are clutter
    many_pairs: list[np.ndarray] = []  # many: every track's segments and last position, drawn at once
    many_colors: list[np.ndarray] = []
    many_last: list[tuple[np.ndarray, Any]] = []
    for n_uav, (uav, series) in enumerate(sorted(tracks.items())):
        color = cmap(n_uav % cmap.N)
        xy = np.asarray(series.xy, dtype=float).reshape(-1, 2)
        segments = _segments(xy)
        total = sum(len(s) for s in segments)
        done = 0
        for seg in segments:  # alpha rises with time: faint = early, solid = late
            if len(seg) >= 2:
                pairs = np.stack([seg[:-1], seg[1:]], axis=1)
                alpha = 0.15 + 0.85 * (done + np.arange(len(pairs))) / max(total - 1, 1)
                colors = np.tile(np.asarray(color), (len(pairs), 1))
                colors[:, 3] = alpha
                if many:
                    many_pairs.append(pairs)
                    many_colors.append(colors)
                else:
                    ax.add_collection(LineCollection(pairs, colors=colors, linewidths=1.6, zorder=4))
            if not many:
                ax.scatter(*seg[0], s=30, facecolor="white", edgecolor=color, lw=1.5, zorder=5)
            done += len(seg)
        finite = xy[np.isfinite(xy).all(axis=1)]
        if len(finite) and many:
            many_last.append((finite[-1], color))
        elif len(finite):
            ax.scatter(*finite[-1], s=45, color=color, edgecolor="black", lw=0.6, zorder=5)
            ax.add_patch(Circle(tuple(finite[-1]), radius, facecolor=color, alpha=0.08, edgecolor=color,
                                lw=1.0, ls="--", zorder=2))
        if not many:
            handles.append(Line2D([], [], color=color, lw=2, label=f"UAV {uav}"))
    if many_pairs:
        ax.add_collection(LineCollection(np.concatenate(many_pairs), colors=np.concatenate(many_colors),
                                         linewidths=0.6, zorder=4))
    if many_last:
        ax.scatter([p[0] for p, _ in many_last], [p[1] for p, _ in many_last], s=10,
                   color=[c for _, c in many_last], edgecolor="black", lw=0.3, zorder=5)
    if many:
        handles += [Line2D([], [], color="0.3", lw=0.8, label=f"{len(tracks)} UAV tracks (colours repeat; no ids, "
                                                              f"starts or coverage discs above {MAX_LABELLED_UAVS})"),
                    Line2D([], [], marker="o", ls="", ms=3, color="0.4", mec="black", label="last position")]
    elif tracks:
        handles += [Line2D([], [], marker="o", ls="", mfc="white", mec="0.2", label="track start (each episode)"),
                    Line2D([], [], marker="o", ls="", color="0.4", mec="black", label="last position"),
                    Circle((0, 0), 1, facecolor="0.5", alpha=0.2, edgecolor="0.3", ls="--",
                           label=f"coverage, {radius:g} m" + ("" if cfg else " (default)"))]
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"Swarm map: {len(tracks)} UAV tracks from {source} over {rec.duration_s:.0f} s "
                 "(faint = early, solid = late)", fontsize=11)
    ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.08), ncol=MAP_LEGEND_COLUMNS, fontsize=8,
              frameon=False)
    fig.tight_layout()
    fig.savefig(path, dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    return f"map: {len(tracks)} UAVs ({source}), {sum(len(v) for v in rec.vehicles):,} vehicle positions" + (
        "" if cfg else ", no config in the file: no roads/RSUs")


def metrics_figure(rec: Recording, path: Path) -> Optional[str]:
    """One panel per step metric over time, faults shaded, episode starts dotted."""
    steps = [m for m in rec.metrics if m.get("scope") == "step"] or rec.metrics
    if not steps:
        return None
    names = sorted({n for m in steps for n in m["values"]},
                   key=lambda n: (list(METRIC_LABELS).index(n) if n in METRIC_LABELS else len(METRIC_LABELS), n))

    def series(name: str) -> np.ndarray:
        return np.array([float(m["values"][name]) if m["values"].get(name) is not None else np.nan for m in steps])

    # a metric that never changes gets a line in the title, not a flat panel
    constant = {}
    for name in names:
        finite = series(name)[np.isfinite(series(name))]
        if finite.size and np.all(finite == finite[0]):
            constant[name] = finite[0]
    varying = [n for n in names if n not in constant]
    shown = varying[:MAX_METRIC_PANELS]
    if not shown:
        shown = names[:1]
    plt = _plt()
    t = np.array([rec.t(m["_log_ns"]) for m in steps])
    episodes = [m.get("episode") for m in steps]
    starts = [t[i] for i in range(1, len(steps)) if episodes[i] != episodes[i - 1]]
    spans = rec.fault_spans()
    cols = 2 if len(shown) > 3 else 1
    rows = math.ceil(len(shown) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(7.0 * cols, 2.1 * rows + 0.8), sharex=True, squeeze=False)
    for ax, name in zip(axes.ravel(), shown):
        y = series(name)
        _shade_faults(ax, spans, rec.duration_s, label=True)
        for s in starts:
            ax.axvline(s, color="0.5", lw=0.6, ls=":")
        ax.plot(t, y, lw=1.0, color="C0")
        ax.set_title(metric_label(name), fontsize=9, loc="left", pad=3)
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[len(shown):]:
        ax.axis("off")
    for ax in axes[-1]:
        ax.set_xlabel("time since recording start (s)")
    ticks = np.array([m["tick"] if isinstance(m.get("tick"), (int, float)) and not isinstance(m.get("tick"), bool)
                      else np.nan for m in steps], dtype=float)  # a forged tick is no tick
    ok = np.isfinite(ticks) & np.isfinite(t)
    tick_axis = ok.sum() >= 2 and np.all(np.diff(t[ok]) >= 0) and np.all(np.diff(ticks[ok]) > 0)
    if tick_axis:
        # the world's tick above, as summary.png and `truav-swarm status` count (recording seconds below:
        # the fault windows and the other pictures of the report are in them)
        tt, kk = t[ok], ticks[ok]
        for ax in axes[0]:
            if ax.has_data():
                top_axis = ax.secondary_xaxis("top", functions=(lambda x: np.interp(x, tt, kk),
                                                               lambda k: np.interp(k, kk, tt)))
                top_axis.tick_params(labelsize=7)
                ax.set_title(ax.get_title(loc="left"), fontsize=9, loc="left", pad=14)  # above the tick labels
    handles, labels = axes.ravel()[0].get_legend_handles_labels()
    if starts:
        from matplotlib.lines import Line2D

        handles.append(Line2D([], [], color="0.5", lw=0.8, ls=":"))
        labels.append("episode start")
    more = f" (first {len(shown)} of {len(varying)})" if len(varying) > len(shown) else ""
    flat = "\n" + textwrap.fill("not drawn, constant over the run: " + ", ".join(
        f"{metric_label(n)} = {v:g}" for n, v in constant.items()), 120) if constant else ""
    title_in = 0.25 * (1 + flat.count("\n"))
    # room for the title's lines and the legend line, in figure units
    top = 1.0 - (title_in + 0.25) / fig.get_figheight()
    if handles:
        fig.legend(handles, labels, loc="upper left", bbox_to_anchor=(0.01, top + 0.25 / fig.get_figheight()),
                   ncol=len(handles), fontsize=8, frameon=False)
    ticked = "; top axis: the world's tick (as summary.png counts)" if tick_axis else ""
    fig.suptitle(f"Step metrics over time{more}: {len(steps)} samples, {len(spans)} fault interval(s){ticked}{flat}",
                 x=0.01, y=0.995, ha="left", fontsize=11)
    fig.tight_layout(rect=(0, 0, 1, top))
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return f"metrics: {len(shown)} series, {len(spans)} faults"


def _latency_scale(ax: Any, axis: str, values: np.ndarray) -> None:
    """Linear unless the tail is far above the median (then symlog, linear below 1 ms)."""
    med, p99 = np.median(values), np.percentile(values, 99)
    if med > 0 and p99 > LOG_SCALE_SPREAD * med:
        (ax.set_yscale if axis == "y" else ax.set_xscale)("symlog", linthresh=1.0)


def agents_figure(rec: Recording, path: Path) -> Optional[str]:
    """Beacon rate heat map, latency median/p99 over time, latency per agent."""
    agents = sorted(u for u, s in rec.beacons.items() if s.log_ns)
    if not agents:
        return None
    plt = _plt()
    edges = _bins(rec)
    width = edges[1] - edges[0]
    rates = np.zeros((len(agents), len(edges) - 1))
    lat_ms: list[np.ndarray] = []
    all_t: list[np.ndarray] = []
    for row, uav in enumerate(agents):
        s = rec.beacons[uav]
        t = (np.asarray(s.log_ns, dtype=np.int64) - rec.first_ns) / NS
        rates[row] = np.histogram(np.minimum(t, edges[-1]), bins=edges)[0] / width
        lat_ms.append((np.asarray(s.log_ns, dtype=np.int64) - np.asarray(s.pub_ns, dtype=np.int64)) / 1e6)
        all_t.append(t)
    spans = rec.fault_spans()
    n = len(agents)
    rows = min(n, MAX_AGENT_ROWS)  # above it: one pixel row per agent, ids on a plain axis, points not boxes
    fig, (ax_rate, ax_time, ax_box) = plt.subplots(
        3, 1, figsize=(12, 6.5 + 0.2 * rows), gridspec_kw={"height_ratios": [1.0 + 0.08 * rows, 1.0, 1.1]})
    ax_time.sharex(ax_rate)
    mesh = ax_rate.pcolormesh(edges, np.arange(n + 1) - 0.5, rates, cmap="viridis", shading="flat", vmin=0)
    cax = ax_rate.inset_axes([1.01, 0.0, 0.012, 1.0])  # outside the axes: keeps the time axes aligned
    fig.colorbar(mesh, cax=cax).set_label("beacons/s")
    for span in spans:
        end = rec.duration_s if span.end_s is None else span.end_s
        ax_rate.axvspan(span.start_s, end, facecolor="none", edgecolor=FAULT_COLORS.get(span.fault, "white"),
                        hatch="//", lw=1.0)
    if n <= MAX_AGENT_ROWS:
        ax_rate.set_yticks(range(n), [f"UAV {u}" for u in agents], fontsize=8 if n < 25 else 6)
    else:
        ax_rate.set_ylabel(f"agent (row; {n} UAVs, ids {agents[0]}..{agents[-1]})")
    ax_rate.set_title(f"Beacons sent per agent, as the recorder heard them ({width:.3g} s bins; dark = agent sent "
                      "none: crashed, frozen or stopped" + ("; hatched = fault" if spans else "")
                      + ")\nThe recorder hears every beacon: what each receiver lost is in links.png",
                      fontsize=10, loc="left")
    t_all, l_all = np.concatenate(all_t), np.concatenate(lat_ms)
    idx = np.clip(np.digitize(t_all, edges) - 1, 0, len(edges) - 2)
    mids, p50, p99 = [], [], []
    for b in range(len(edges) - 1):
        sel = l_all[idx == b]
        if sel.size:
            mids.append((edges[b] + edges[b + 1]) / 2)
            p50.append(np.percentile(sel, 50))
            p99.append(np.percentile(sel, 99))
    _shade_faults(ax_time, spans, rec.duration_s, label=True)
    ax_time.plot(mids, p50, color="C0", lw=1.2, marker=".", ms=3, label="median")
    ax_time.plot(mids, p99, color="C3", lw=1.0, marker=".", ms=3, label="p99")
    ax_time.set_xlabel("time since recording start (s)")
    ax_time.set_ylabel("latency (ms)")
    ax_time.set_ylim(0, max(p99) * 1.35 if p99 else 1.0)  # headroom for the legend
    _latency_scale(ax_time, "y", l_all)
    ax_time.grid(alpha=0.3)
    ax_time.legend(fontsize=8, loc="upper left", ncol=4, frameon=False)
    ax_time.set_title("One-way beacon latency at the recorder, all agents (receive time - sender timestamp)",
                      fontsize=10, loc="left")
    ax_rate.set_xlim(edges[0], edges[-1])
    if n <= MAX_AGENT_ROWS:
        ax_box.boxplot(lat_ms, positions=range(n), showfliers=False, whis=(1, 99), widths=0.6,
                       medianprops={"color": "C0"})
        ax_box.set_xticks(range(n), [str(u) for u in agents], fontsize=8 if n < 25 else 6)
        ax_box.set_xlabel("UAV")
        box_title = "Beacon latency per agent (box: quartiles, whiskers: p1-p99)"
    else:
        ax_box.plot(agents, [np.median(v) for v in lat_ms], ".", ms=3, color="C0", label="median")
        ax_box.plot(agents, [np.percentile(v, 99) for v in lat_ms], ".", ms=3, color="C3", label="p99")
        ax_box.legend(fontsize=8, loc="upper left", ncol=2, frameon=False)
        ax_box.set_xlabel("UAV id")
        box_title = f"Beacon latency per agent (median and p99 of each; boxes above {MAX_AGENT_ROWS} agents are clutter)"
    ax_box.set_ylabel("latency (ms)")
    _latency_scale(ax_box, "y", l_all)
    ax_box.grid(alpha=0.3, axis="y")
    ax_box.set_title(box_title, fontsize=10, loc="left")
    fig.tight_layout()
    fig.savefig(path, dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    return (f"agents: {n} beaconing, median latency {np.median(l_all):.2f} ms, "
            f"p99 {np.percentile(l_all, 99):.2f} ms")

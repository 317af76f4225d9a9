"""``truav report FILE``: pictures of a recorded swarm run, and its metrics as CSV.

Writes into ``--out`` (default ``<file stem>_report/`` next to the file):

``map.png``       roads and RSUs (from the run config stored in the file, when
                  there is one), the vehicle density heat map (from
                  ``world/positions``), each UAV's track fading in over time
                  (from beacons; observations or positions when there are
                  none) and coverage discs at its last position;
``metrics.png``   every step metric over time, fault intervals shaded,
                  episode starts dotted;
``agents.png``    beacon rate per agent over time (a heat map: silent agents
                  show as gaps), one-way beacon latency per agent
                  (receive time - sender timestamp: same-host clocks, so it is
                  the bus latency) and its median/p99 over time;
``metrics.csv``   one row per metrics message (step and episode scope).

Only what is in the file is drawn; a figure with nothing to show is skipped
and said so.  Payloads are decoded leniently (msgpack maps with the
envelope), so a recording with odd messages still reports.
"""

from __future__ import annotations

import csv
import math
import os
import tomllib
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import msgpack
import numpy as np

from recorder.metadata import read_config_toml
from recorder.reader import iter_messages, open_source, probe

MAP_FILE, METRICS_FIG_FILE, AGENTS_FILE, METRICS_CSV_FILE = "map.png", "metrics.png", "agents.png", "metrics.csv"
REPORT_DIR_SUFFIX = "_report"
DPI = 110
NS = 1e9
HEAT_BINS = 120  # heat map cells per axis
MAX_VEHICLE_POINTS = 4_000_000  # keep every k-th positions message beyond this (bounded memory)
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
}


def metric_label(name: str) -> str:
    return METRIC_LABELS.get(name, name.replace("_", " "))
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
CSV_FIXED = ("time_s", "log_time_ns", "publish_time_ns", "src", "scope", "episode", "tick")


class ReportError(ValueError):
    """A user mistake: missing file, not an MCAP file."""


# --- what is read from the file ------------------------------------------------------------
@dataclass
class Series:
    """Receive time, publish time and position samples of one UAV."""

    log_ns: list[int] = field(default_factory=list)
    pub_ns: list[int] = field(default_factory=list)
    xy: list[tuple[float, float]] = field(default_factory=list)


@dataclass
class FaultSpan:
    fault: str
    target: str
    start_s: float
    end_s: Optional[float]  # None: never ended within the recording


@dataclass
class MapConfig:
    """What the map needs from the run config."""

    area_m: float
    block_m: float
    rsus: list[tuple[float, float]]
    majors: list[tuple[float, float]]
    comm_range_m: float


@dataclass
class Recording:
    first_ns: Optional[int] = None
    last_ns: Optional[int] = None
    messages: int = 0
    undecodable: int = 0
    beacons: dict[int, Series] = field(default_factory=lambda: defaultdict(Series))
    obs: dict[int, Series] = field(default_factory=lambda: defaultdict(Series))
    positions_uavs: dict[int, Series] = field(default_factory=lambda: defaultdict(Series))
    vehicles: list[np.ndarray] = field(default_factory=list)
    vehicle_stride: int = 1  # keep every stride-th positions message
    positions_seen: int = 0
    metrics: list[dict[str, Any]] = field(default_factory=list)  # decoded metrics bodies + times
    faults: list[tuple[int, dict[str, Any]]] = field(default_factory=list)  # (log_ns, body)
    config: Optional[MapConfig] = None

    def t(self, ns: int) -> float:
        """Seconds since the first message."""
        return (ns - (self.first_ns or 0)) / NS

    @property
    def duration_s(self) -> float:
        return 0.0 if self.first_ns is None or self.last_ns is None else (self.last_ns - self.first_ns) / NS

    def tracks(self) -> tuple[str, dict[int, Series]]:
        """The best source of UAV tracks: beacons, else observations, else positions messages."""
        for name, source in (("beacons", self.beacons), ("observations", self.obs),
                             ("positions", self.positions_uavs)):
            if any(s.xy for s in source.values()):
                return name, source
        return "none", {}

    def fault_spans(self) -> list[FaultSpan]:
        """Start/end events paired per (fault, target); an unmatched start lasts to the end."""
        open_: dict[tuple[str, str], float] = {}
        spans: list[FaultSpan] = []
        for log_ns, body in sorted(self.faults, key=lambda f: f[0]):
            k = (str(body.get("fault")), str(body.get("target")))
            if body.get("phase") == "start":
                open_.setdefault(k, self.t(log_ns))
            elif body.get("phase") == "end":
                start = open_.pop(k, 0.0)
                spans.append(FaultSpan(k[0], k[1], start, self.t(log_ns)))
        spans += [FaultSpan(f, tg, s, None) for (f, tg), s in open_.items()]
        return sorted(spans, key=lambda s: s.start_s)


def _xy(v: Any) -> Optional[tuple[float, float]]:
    try:
        x, y = float(v[0]), float(v[1])
    except (TypeError, ValueError, IndexError, KeyError):
        return None
    return (x, y) if math.isfinite(x) and math.isfinite(y) else None


def _uav(body: dict, key: str) -> Optional[int]:
    uav = body.get("uav")
    if type(uav) is int:
        return uav
    parts = key.split("/")
    return int(parts[3]) if len(parts) > 3 and parts[2] == "uav" and parts[3].isdigit() else None


def load_recording(path: Path) -> Recording:
    """One pass over the bus channels, keeping what the figures need."""
    rec = Recording()
    for key, payload, log_ns, pub_ns in iter_messages(path):
        rec.messages += 1
        rec.first_ns = log_ns if rec.first_ns is None else min(rec.first_ns, log_ns)
        rec.last_ns = log_ns if rec.last_ns is None else max(rec.last_ns, log_ns)
        try:
            body = msgpack.unpackb(payload)
        except Exception:  # any msgpack failure: the message is just not drawn
            rec.undecodable += 1
            continue
        if not isinstance(body, dict):
            rec.undecodable += 1
            continue
        kind = body.get("kind")
        if kind in ("beacon", "obs"):
            uav, xy = _uav(body, key), _xy(body.get("pos"))
            if uav is not None:
                series = (rec.beacons if kind == "beacon" else rec.obs)[uav]
                series.log_ns.append(log_ns)
                series.pub_ns.append(pub_ns)
                if xy is not None:
                    series.xy.append(xy)
                else:
                    series.xy.append((math.nan, math.nan))
        elif kind == "positions":
            _add_positions(rec, body, log_ns, pub_ns)
        elif kind == "metrics" and isinstance(body.get("values"), dict):
            rec.metrics.append({**body, "_log_ns": log_ns, "_pub_ns": pub_ns})
        elif kind == "fault":
            rec.faults.append((log_ns, body))
    rec.config = _map_config(path)
    return rec


def _add_positions(rec: Recording, body: dict, log_ns: int, pub_ns: int) -> None:
    uavs = body.get("uavs")
    if isinstance(uavs, list):
        for i, p in enumerate(uavs):
            xy = _xy(p)
            if xy is not None:
                s = rec.positions_uavs[i]
                s.log_ns.append(log_ns)
                s.pub_ns.append(pub_ns)
                s.xy.append(xy)
    vehicles = body.get("vehicles")
    rec.positions_seen += 1
    if not isinstance(vehicles, list) or not vehicles or (rec.positions_seen - 1) % rec.vehicle_stride:
        return
    try:
        arr = np.asarray(vehicles, dtype=np.float32).reshape(-1, 2)
    except (TypeError, ValueError):
        return
    rec.vehicles.append(arr[np.isfinite(arr).all(axis=1)])
    if sum(len(a) for a in rec.vehicles) > MAX_VEHICLE_POINTS:  # halve what we keep, double the stride
        rec.vehicles = rec.vehicles[::2]
        rec.vehicle_stride *= 2


def _map_config(path: Path) -> Optional[MapConfig]:
    """Roads, RSUs and range from the run config stored as metadata (defaults filled in)."""
    text = read_config_toml(path)
    if text is None:
        return None
    try:
        from truav.config import config_from_dict

        cfg = config_from_dict(tomllib.loads(text))
    except Exception:  # an old or foreign config: draw without roads rather than fail
        return None
    block = cfg.roads.block_m
    return MapConfig(
        area_m=cfg.scenario.area_m, block_m=block,
        rsus=[(i * block, j * block) for i, j in cfg.scenario.rsu_intersections],
        majors=[(i * block, j * block) for i, j in cfg.roads.major_intersections],
        comm_range_m=cfg.scenario.comm_range_m,
    )


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
    from truav.swarm.plots import MAX_LABELLED_UAVS
    many = len(tracks) > MAX_LABELLED_UAVS  # thin tracks, no discs, no per-UAV legend: a hundred of them are clutter
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
                ax.add_collection(LineCollection(pairs, colors=colors, linewidths=0.6 if many else 1.6, zorder=4))
            if not many:
                ax.scatter(*seg[0], s=30, facecolor="white", edgecolor=color, lw=1.5, zorder=5)
            done += len(seg)
        finite = xy[np.isfinite(xy).all(axis=1)]
        if len(finite):
            ax.scatter(*finite[-1], s=10 if many else 45, color=color, edgecolor="black", lw=0.3 if many else 0.6,
                       zorder=5)
            if not many:
                ax.add_patch(Circle(tuple(finite[-1]), radius, facecolor=color, alpha=0.08, edgecolor=color,
                                    lw=1.0, ls="--", zorder=2))
        if not many:
            handles.append(Line2D([], [], color=color, lw=2, label=f"UAV {uav}"))
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
    handles, labels = axes.ravel()[0].get_legend_handles_labels()
    if starts:
        from matplotlib.lines import Line2D

        handles.append(Line2D([], [], color="0.5", lw=0.8, ls=":"))
        labels.append("episode start")
    top = 1.0 - 0.5 / fig.get_figheight()  # room for the title line and the legend line, in figure units
    if handles:
        fig.legend(handles, labels, loc="upper left", bbox_to_anchor=(0.01, top + 0.25 / fig.get_figheight()),
                   ncol=len(handles), fontsize=8, frameon=False)
    more = f" (first {len(shown)} of {len(varying)})" if len(varying) > len(shown) else ""
    flat = "; constant: " + ", ".join(f"{metric_label(n)} = {v:g}" for n, v in constant.items()) if constant else ""
    fig.suptitle(f"Step metrics over time{more}: {len(steps)} samples, {len(spans)} fault interval(s){flat}",
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
    fig, (ax_rate, ax_time, ax_box) = plt.subplots(
        3, 1, figsize=(12, 6.5 + 0.2 * n), gridspec_kw={"height_ratios": [1.0 + 0.08 * n, 1.0, 1.1]})
    ax_time.sharex(ax_rate)
    mesh = ax_rate.pcolormesh(edges, np.arange(n + 1) - 0.5, rates, cmap="viridis", shading="flat", vmin=0)
    cax = ax_rate.inset_axes([1.01, 0.0, 0.012, 1.0])  # outside the axes: keeps the time axes aligned
    fig.colorbar(mesh, cax=cax).set_label("beacons/s")
    for span in spans:
        end = rec.duration_s if span.end_s is None else span.end_s
        ax_rate.axvspan(span.start_s, end, facecolor="none", edgecolor=FAULT_COLORS.get(span.fault, "white"),
                        hatch="//", lw=1.0)
    ax_rate.set_yticks(range(n), [f"UAV {u}" for u in agents], fontsize=8 if n < 25 else 6)
    ax_rate.set_title(f"Beacon rate per agent ({width:.3g} s bins; dark = agent silent or beacons lost"
                      + ("; hatched = fault" if spans else "") + ")", fontsize=10, loc="left")
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
    ax_time.set_title("One-way beacon latency, all agents (receive time - sender timestamp)", fontsize=10, loc="left")
    ax_rate.set_xlim(edges[0], edges[-1])
    ax_box.boxplot(lat_ms, positions=range(n), showfliers=False, whis=(1, 99), widths=0.6,
                   medianprops={"color": "C0"})
    ax_box.set_xticks(range(n), [str(u) for u in agents], fontsize=8 if n < 25 else 6)
    ax_box.set_xlabel("UAV")
    ax_box.set_ylabel("latency (ms)")
    _latency_scale(ax_box, "y", l_all)
    ax_box.grid(alpha=0.3, axis="y")
    ax_box.set_title("Beacon latency per agent (box: quartiles, whiskers: p1-p99)", fontsize=10, loc="left")
    fig.tight_layout()
    fig.savefig(path, dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    return (f"agents: {n} beaconing, median latency {np.median(l_all):.2f} ms, "
            f"p99 {np.percentile(l_all, 99):.2f} ms")


def write_metrics_csv(rec: Recording, path: Path) -> str:
    """Every metrics message, ordered by receive time; one column per metric name."""
    names = sorted({n for m in rec.metrics for n in m["values"]})
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow([*CSV_FIXED, *names])
        for m in sorted(rec.metrics, key=lambda m: m["_log_ns"]):
            values = m["values"]
            writer.writerow([f"{rec.t(m['_log_ns']):.6f}", m["_log_ns"], m["_pub_ns"], m.get("src", ""),
                             m.get("scope", ""), m.get("episode", ""), m.get("tick", ""),
                             *("" if values.get(n) is None else repr(float(values[n])) for n in names)])
    return f"metrics.csv: {len(rec.metrics)} rows x {len(names)} metrics"


# --- entry point -------------------------------------------------------------------------------------
def default_out_dir(path: Path) -> Path:
    return path.with_name(path.stem + REPORT_DIR_SUFFIX)


def report(path: str | os.PathLike[str], out: str | os.PathLike[str] | None = None) -> tuple[Path, list[str]]:
    """Write the report of ``path`` into ``out``; returns (out dir, one line per output or skip)."""
    path = Path(path)
    if not path.is_file():
        raise ReportError(f"{path}: no such file")
    try:
        with open_source(path) as stream:
            state = probe(stream)
    except ValueError as exc:
        raise ReportError(f"{path}: {exc}") from None
    out_dir = Path(out) if out is not None else default_out_dir(path)
    if out_dir.exists() and not out_dir.is_dir():
        raise ReportError(f"{out_dir} exists and is not a directory")
    out_dir.mkdir(parents=True, exist_ok=True)
    rec = load_recording(path)
    lines = [f"{path}: {rec.messages} messages over {rec.duration_s:.1f} s"
             + ("" if state.finished else " (unfinished file: read up to its last complete chunk)")]
    for fname, make, what in ((MAP_FILE, map_figure, "no positions"), (METRICS_FIG_FILE, metrics_figure, "no metrics"),
                              (AGENTS_FILE, agents_figure, "no beacons")):
        done = make(rec, out_dir / fname)
        lines.append(f"  {out_dir / fname}  ({done})" if done else f"  {fname}: skipped, {what} in the recording")
    lines.append(f"  {out_dir / METRICS_CSV_FILE}  ({write_metrics_csv(rec, out_dir / METRICS_CSV_FILE)})")
    return out_dir, lines

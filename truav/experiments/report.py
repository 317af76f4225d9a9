"""Tables and figures of an experiment from its finished cells.

- tidy CSV: one row per (scheme, setting, seed, phase, episode window):
  training windows of `window` episodes, plus one "eval" row per seed over
  its evaluation episodes;
- summary: per (scheme, setting), mean and 95% Student-t interval over seeds
  of each seed's evaluation mean (and of its last training window);
- figures: metric-versus-setting panels (one line per scheme, 95% bands; with fewer than
  MIN_SEEDS_FOR_BAND seeds each seed instead) and
  convergence curves (sliding-window training curves).
"""

from __future__ import annotations

import csv
import os
import warnings
from pathlib import Path

import numpy as np  # noqa: E402

from truav.experiments.cells import CellResult  # noqa: E402
from truav.stats import MIN_SEEDS_FOR_BAND, mean_ci, sliding_mean  # noqa: E402

METRICS = ("coverage_pct", "pdr", "delay_ms", "energy_j", "energy_above_hover_j", "throughput_kbps",
           "generated", "delivered", "dropped", "reward", "ctrl_up_msgs", "ctrl_up_bytes", "ctrl_down_msgs",
           "ctrl_down_bytes", "ctrl_airtime_s", "ctrl_energy_j", "ctrl_delay_ms")
"""Columns of the tidy CSV (a scheme lacking one, e.g. TRUAV's control-plane
counters, writes 0 for counters and blank otherwise)."""
COUNTERS = {"ctrl_up_msgs", "ctrl_up_bytes", "ctrl_down_msgs", "ctrl_down_bytes", "ctrl_airtime_s",
            "ctrl_energy_j"}

# The paper's four panels: (metric, axis label, scale)
PANELS = (
    ("coverage_pct", "network coverage (%)", 1.0),
    ("delay_ms", "average relay delay (ms)", 1.0),
    ("energy_above_hover_j", "energy above hover (kJ per UAV per episode)", 1e-3),
    ("pdr", "packet delivery ratio (%)", 100.0),
)
# What a metric can be: a t-interval of few seeds is wide, and a band is never drawn past these.
BAND_LIMITS = {"coverage_pct": (0.0, 100.0), "delay_ms": (0.0, np.inf), "pdr": (0.0, 100.0)}


def _band(name: str, m: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = BAND_LIMITS.get(name, (-np.inf, np.inf))
    return np.clip(m - h, lo, hi), np.clip(m + h, lo, hi)


SCHEME_STYLE = {"truav": ("TRUAV (distributed Q-learning)", "C0", "o"),
                "central": ("Centralized MA-SAC", "C3", "s"),
                "patrol": ("Trajectory-knowledge patrol", "C2", "^"),
                "patrol_ctrl": ("Patrol + centralized control plane", "C7", "v"),
                "federated": ("Federated TRUAV (learning, Q-sharing)", "C1", "D"),
                "truav_online": ("TRUAV learning online, no sharing", "C4", "P"),
                "spread": ("Decentralized heuristic (spread)", "C5", "X"),
                "claim": ("Decentralized heuristic, climbing (claim)", "C6", "*"),
                "ppo-claim": ("Learned clone of the climbing heuristic (ppo-claim)", "C8", "p")}


def _pyplot():
    """matplotlib on first use: `truav --help` and a usage error need not load it (~1 s)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _label(scheme: str) -> str:
    return SCHEME_STYLE.get(scheme, (scheme, None, None))[0]


def _style(scheme: str, index: int) -> tuple[str, str, str]:
    """(label, colour, marker) of a scheme; one without a style (an agent class) gets a free colour."""
    if scheme in SCHEME_STYLE:
        return SCHEME_STYLE[scheme]
    used = {c for _, c, _ in SCHEME_STYLE.values()}
    free = [c for c in (f"C{i}" for i in range(10)) if c not in used]
    return scheme, free[index % len(free)], "D"


def _column(metrics: dict[str, np.ndarray], name: str, shape) -> np.ndarray:
    if name in metrics:
        return metrics[name]
    return np.zeros(shape) if name in COUNTERS else np.full(shape, np.nan)


def _fmt(x: float) -> str:
    return "" if not np.isfinite(x) else f"{x:.6g}"


def setting_of(r: CellResult, columns: tuple[str, ...]) -> dict[str, float]:
    sc = dict((k, v) for s, k, v in r.cell.overrides if s == "scenario")
    values = {"speed_mps": r.cell.speed, "n_uavs": sc.get("n_uavs"), "n_vehicles": sc.get("n_vehicles")}
    return {c: values[c] for c in columns}


def write_tidy_csv(path: Path, results: list[CellResult], window: int, setting: tuple[str, ...],
                   defaults: dict[str, float]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["scheme", *setting, "seed", "phase", "window", "episode_start", "episode_end", *METRICS])
        for r in results:
            st = {k: (defaults[k] if v is None else v) for k, v in setting_of(r, setting).items()}
            for phase, metrics in (("train", r.train), ("eval", r.eval)):
                if not metrics:
                    continue
                n_ep = next(iter(metrics.values())).shape[0]
                size = window if phase == "train" else n_ep
                for b, seed in enumerate(r.cell.seeds):
                    for k, lo in enumerate(range(0, n_ep, size)):
                        hi = min(lo + size, n_ep)
                        vals = []
                        for name in METRICS:
                            col = _column(metrics, name, (n_ep, len(r.cell.seeds)))[lo:hi, b]
                            vals.append(_fmt(np.nanmean(col)) if np.isfinite(col).any() else "")
                        w.writerow([r.cell.scheme, *(f"{st[c]:g}" for c in setting), seed, phase, k, lo, hi - 1,
                                    *vals])
    os.replace(tmp, path)


def per_seed(results: list[CellResult], phase: str, last: int | None = None) -> dict[tuple, dict[str, np.ndarray]]:
    """{(scheme, setting...): {metric: (seeds,)}}: each seed's mean over the
    phase's episodes (the last `last` training episodes if given)."""
    groups: dict[tuple, dict[str, list[np.ndarray]]] = {}
    for r in results:
        metrics = r.eval if phase == "eval" else r.train
        if not metrics:
            continue
        key = (r.cell.scheme, r.cell.speed, *(v for _, _, v in r.cell.overrides))
        g = groups.setdefault(key, {})
        n_ep = next(iter(metrics.values())).shape[0]
        lo = 0 if last is None else max(0, n_ep - last)
        names = set(METRICS) | set(metrics)
        for name in names:
            col = _column(metrics, name, (n_ep, len(r.cell.seeds)))[lo:]
            with np.errstate(all="ignore"):
                g.setdefault(name, []).append(np.nanmean(col, axis=0) if np.isfinite(col).any() else
                                              np.full(col.shape[1], np.nan))
    return {k: {n: np.concatenate(v) for n, v in g.items()} for k, g in groups.items()}


def summary_rows(results: list[CellResult], window: int) -> list[dict[str, object]]:
    rows = []
    ev, tr = per_seed(results, "eval"), per_seed(results, "train", last=window)
    by_key = {(r.cell.scheme, r.cell.speed, *(v for _, _, v in r.cell.overrides)): r for r in results}
    for key in sorted(set(ev) | set(tr), key=lambda k: (list(SCHEME_STYLE).index(k[0]) if k[0] in SCHEME_STYLE
                                                         else 9, k[1:])):
        r = by_key[key]
        row: dict[str, object] = {"scheme": key[0], "speed_mps": key[1]}
        row.update({k: v for (_, k, v) in r.cell.overrides})
        for phase, data in (("eval", ev.get(key)), ("train_last", tr.get(key))):
            if data is None:
                continue
            row[f"{phase}_seeds"] = int(np.isfinite(data["coverage_pct"]).sum())
            for name in METRICS:
                with warnings.catch_warnings():  # a metric a scheme lacks is all-NaN
                    warnings.simplefilter("ignore", RuntimeWarning)
                    m, h = mean_ci(data[name])
                row[f"{phase}_{name}_mean"], row[f"{phase}_{name}_ci95"] = float(m), float(h)
            if phase == "eval":  # for figures (too few seeds for a band: each seed); not a CSV column
                row[SEED_VALUES] = {name: np.asarray(data[name], float) for name, _, _ in PANELS}
        rows.append(row)
    return rows


SEED_VALUES = "_eval_seed_values"
"""Key of a summary row's per-seed evaluation means of the PANELS metrics (written to no CSV)."""


def write_summary_csv(path: Path, rows: list[dict[str, object]]) -> None:
    keys: list[str] = []
    for row in rows:
        keys += [k for k in row if k not in keys and k != SEED_VALUES]
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for row in rows:
            w.writerow({k: (_fmt(v) if isinstance(v, float) else v) for k, v in row.items() if k != SEED_VALUES})
    os.replace(tmp, path)


def _pm(row, name, scale=1.0, digits=2):
    m, h = row.get(f"eval_{name}_mean", np.nan), row.get(f"eval_{name}_ci95", np.nan)
    if not np.isfinite(m):
        return "—"
    return f"{m * scale:.{digits}f} ± {h * scale:.{digits}f}" if np.isfinite(h) else f"{m * scale:.{digits}f}"


def markdown_table(rows: list[dict[str, object]], setting: tuple[str, ...]) -> str:
    """Evaluation means ± 95% intervals over seeds, one line per scheme and setting."""
    cols = [("coverage %", "coverage_pct", 1.0, 1), ("PDR %", "pdr", 100.0, 1), ("delay ms", "delay_ms", 1.0, 1),
            ("energy kJ/UAV", "energy_j", 1e-3, 2), ("above hover kJ/UAV", "energy_above_hover_j", 1e-3, 2),
            ("ctrl kB/episode", "ctrl_up_bytes", None, 1)]
    head = ["scheme", *setting, *(c[0] for c in cols)]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        cells = [str(row["scheme"]), *(f"{row.get(s, np.nan):g}" for s in setting)]
        for _, name, scale, digits in cols:
            if name == "ctrl_up_bytes":
                total = row.get("eval_ctrl_up_bytes_mean", 0.0) + row.get("eval_ctrl_down_bytes_mean", 0.0)
                cells.append(f"{total / 1e3:.1f}")
            else:
                cells.append(_pm(row, name, scale, digits))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def versus_figure(rows: list[dict[str, object]], x: str, xlabel: str, path: Path, title: str,
                  group: str | None = None) -> Path:
    """The four panels (coverage, delay, energy, PDR) against x, one line per
    scheme (and per `group` value, dashed for the second), 95% bands."""
    plt = _pyplot()
    fig, axes = plt.subplots(2, 2, figsize=(10.5, 7.4))
    schemes = [s for s in SCHEME_STYLE if any(r["scheme"] == s for r in rows)] + \
        sorted({str(r["scheme"]) for r in rows} - set(SCHEME_STYLE))
    groups = [None] if group is None else sorted({r.get(group) for r in rows})
    for ax, (name, label, scale) in zip(axes.ravel(), PANELS):
        for s in schemes:
            lab, color, marker = _style(s, schemes.index(s) - sum(k in SCHEME_STYLE for k in schemes))
            for gi, gv in enumerate(groups):
                sel = sorted((r for r in rows if r["scheme"] == s and (group is None or r.get(group) == gv)),
                             key=lambda r: r[x])
                if not sel:
                    continue
                xs = np.array([r[x] for r in sel], float)
                m = np.array([r.get(f"eval_{name}_mean", np.nan) for r in sel], float) * scale
                h = np.array([r.get(f"eval_{name}_ci95", np.nan) for r in sel], float) * scale
                text = lab if group is None else f"{lab}, {group.replace('n_', '')}={gv:g}"
                ax.plot(xs, m, marker=marker, color=color, ls="-" if gi == 0 else "--", lw=1.6, label=text)
                few = [r for r in sel if r.get("eval_seeds", 0) < MIN_SEEDS_FOR_BAND]
                for r in few:  # too few seeds for a band: each seed's value
                    v = np.asarray((r.get(SEED_VALUES) or {}).get(name, []), float) * scale
                    ax.scatter(np.full(v.size, r[x], float), v, s=14, marker=marker, facecolor="none",
                               edgecolor=color, lw=0.8, alpha=0.8, zorder=3)
                if not few and np.isfinite(h).any():
                    ax.fill_between(xs, *_band(name, m, h), color=color, alpha=0.18, lw=0)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    handles, labels = _legend(axes)
    fig.legend(handles, labels, loc="lower center", ncol=min(3, len(labels)), frameon=False)
    fig.suptitle(title)
    fig.tight_layout(rect=(0, 0.06 if len(labels) <= 3 else 0.1, 1, 0.96))
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


CONVERGENCE_MIN_WIDTH_IN = 7.5
"""Narrowest convergence figure (inches): its title and a legend entry fit."""
LEGEND_ENTRY_WIDTH_IN = 3.6
"""About the width of one legend entry (the schemes' labels run to ~40 characters)."""


def convergence_figure(results: list[CellResult], path: Path, window: int, title: str) -> Path:
    """Training curves: rows = the four metrics, columns = speeds, one line per
    scheme ({window}-episode sliding mean, mean over seeds, 95% band)."""
    data: dict[tuple[str, float], dict[str, np.ndarray]] = {}
    for r in results:
        key = (r.cell.scheme, r.cell.speed)
        d = data.setdefault(key, {})
        for name, _, _ in PANELS:
            col = _column(r.train, name, next(iter(r.train.values())).shape)
            d[name] = col if name not in d else _hcat(d[name], col)
    speeds = sorted({k[1] for k in data})
    schemes = [s for s in SCHEME_STYLE if any(k[0] == s for k in data)] + \
        sorted({k[0] for k in data} - set(SCHEME_STYLE))
    plt = _pyplot()
    # at one or two speeds the columns alone are narrower than the title and the legend: a minimum width
    width, height = max(3.3 * len(speeds), CONVERGENCE_MIN_WIDTH_IN), 2.5 * len(PANELS)
    fig, axes = plt.subplots(len(PANELS), len(speeds), figsize=(width, height), squeeze=False, sharex="col")
    for j, v in enumerate(speeds):
        for i, (name, label, scale) in enumerate(PANELS):
            ax = axes[i, j]
            for s in schemes:
                if (s, v) not in data:
                    continue
                lab, color, _ = _style(s, schemes.index(s) - sum(k in SCHEME_STYLE for k in schemes))
                raw = data[(s, v)][name] * scale
                smooth = sliding_mean(raw, window, axis=0)
                m, h = mean_ci(smooth, axis=1)
                xs = np.arange(1, len(m) + 1)
                ax.plot(xs, m, color=color, lw=1.3, label=lab)
                if smooth.shape[1] < MIN_SEEDS_FOR_BAND:
                    if smooth.shape[1] > 1:  # too few seeds for a band: each seed, thin
                        ax.plot(xs, smooth, color=color, lw=0.6, alpha=0.4)
                elif np.isfinite(h).any():
                    ax.fill_between(xs, *_band(name, m, h), color=color, alpha=0.2, lw=0)
            if i == 0:
                ax.set_title(f"{v:g} m/s")
            if j == 0:
                ax.set_ylabel(label, fontsize=8)
            if i == len(PANELS) - 1:
                ax.set_xlabel("episode")
            ax.grid(alpha=0.3)
    handles, labels = _legend(axes)
    ncol = max(1, min(len(labels), int(width // LEGEND_ENTRY_WIDTH_IN)))
    rows = -(-len(labels) // ncol)
    fig.legend(handles, labels, loc="lower center", ncol=ncol, frameon=False)
    fig.suptitle(title)
    fig.tight_layout(rect=(0, (0.15 + 0.3 * rows) / height, 1, 0.97))
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _legend(axes) -> tuple[list, list[str]]:
    """One legend entry per label over all panels."""
    seen: dict[str, object] = {}
    for ax in axes.ravel():
        for h, lab in zip(*ax.get_legend_handles_labels()):
            seen.setdefault(lab, h)
    return list(seen.values()), list(seen)


def _hcat(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Side by side over seeds; a shorter run (fewer episodes) is NaN-padded."""
    n = max(a.shape[0], b.shape[0])
    pad = lambda x: np.vstack([x, np.full((n - x.shape[0], x.shape[1]), np.nan)])  # noqa: E731
    return np.hstack([pad(a), pad(b)])

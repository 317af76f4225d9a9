"""The pictures tell the truth at a glance (issue 25): checked on matplotlib's objects, not pixels."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from truav.config import Config  # noqa: E402
from truav.faults import plan_from_dict  # noqa: E402
from truav.swarm.monitor import Monitor  # noqa: E402


@pytest.fixture
def figures(monkeypatch):
    """The figures a plotting function closes, kept open for inspection."""
    kept = []
    monkeypatch.setattr(plt, "close", lambda fig=None: kept.append(fig))
    yield kept
    monkeypatch.undo()
    for fig in kept:
        plt.close(fig)


def _monitor(cfg: Config, n_uavs: int, ticks: int, episodes_heard: int) -> Monitor:
    """The first ``ticks`` world ticks of a run; as the world sends them, an episode's done tick
    (every steps + 1-th) has no step metrics."""
    rng = np.random.default_rng(0)
    m = Monitor(n_uavs, period_s=0.1)
    for u in range(n_uavs):
        start = rng.uniform(0, cfg.scenario.area_m, 2)
        m.tracks[u] = [tuple(start + 10.0 * t * rng.uniform(-1, 1, 2)) for t in range(ticks)]
    per = cfg.scenario.steps_per_episode + 1
    acting = [t for t in range(ticks) if t % per != per - 1]
    m.coverage = [(t, 10.0 + (t % 7)) for t in acting]
    m.hovering = [(t, 0.0) for t in acting]
    m.episodes = [{} for _ in range(episodes_heard)]
    m.vehicles = [tuple(p) for p in rng.uniform(0, cfg.scenario.area_m, (50, 2))]
    return m


def _texts(ax) -> list[str]:
    return [t.get_text() for t in ax.texts]


def test_summary_shades_fault_windows_and_counts_finished_episodes(tmp_path, figures):
    from truav.analysis.swarm_plots import swarm_figure
    cfg = Config().replace(scenario={"steps_per_episode": 20})
    plan = plan_from_dict({"fault": [{"kind": "loss", "start": 2.0, "duration": 3.0, "probability": 0.5},
                                     {"kind": "crash", "start": 10.0, "uav": 1}]})
    # 6 episodes of 20 steps (21 ticks) finished, the 7th cut short at tick 130
    swarm_figure(cfg, _monitor(cfg, 5, 131, 6), tmp_path / "s.png", plan=plan, episodes_done=6)
    fig = figures[-1]
    tracks_ax, tl, miss_ax = fig.axes[:3]
    assert tracks_ax.get_title() == "UAV tracks in episode 7 (cut short; 6 finished)"
    for ax in (tl, miss_ax):  # a span per fault, in ticks (10 Hz): loss 20-50, the crash from 100 to the end
        spans = sorted((p.get_x(), p.get_x() + p.get_width()) for p in ax.patches)
        assert np.array(spans) == pytest.approx(np.array([[20.0, 50.0], [100.0, 130.0]]))
    assert [t.get_text() for t in tl.get_legend().get_texts()] == ["loss, 2-5 s", "crash 1, 10-end s"]


def test_summary_title_of_a_finished_run(tmp_path, figures):
    from truav.analysis.swarm_plots import swarm_figure
    cfg = Config().replace(scenario={"steps_per_episode": 20})
    swarm_figure(cfg, _monitor(cfg, 5, 6 * 21, 6), tmp_path / "s.png")  # 6 episodes, each 20 steps and done
    assert figures[-1].axes[0].get_title() == "UAV tracks in the last episode (6 of 6)"  # was "7 of 7"
    separators = sorted(line.get_xdata()[0] for line in figures[-1].axes[1].lines[1:])
    assert separators == [k * 21 - 0.5 for k in range(1, 6)]  # between a done tick and the next episode
    assert figures[-1].axes[1].get_legend() is None  # no plan: nothing shaded
    assert not figures[-1].axes[1].patches


@pytest.mark.parametrize("n", [20, 100])
def test_summary_map_of_many_uavs_stays_readable(tmp_path, figures, n):
    from truav.analysis.swarm_plots import MAX_LABELLED_UAVS, swarm_figure
    cfg = Config().replace(scenario={"steps_per_episode": 20, "n_uavs": n})
    swarm_figure(cfg, _monitor(cfg, n, 21, 1), tmp_path / "s.png")
    ax = figures[-1].axes[0]
    labels = [t for t in _texts(ax) if t.isdigit()]
    discs = [p for p in ax.patches if isinstance(p, matplotlib.patches.Circle)]
    if n <= MAX_LABELLED_UAVS:
        assert len(labels) == n and len(discs) == n
    else:  # ids and discs of a hundred UAVs are a blot: none, thin tracks
        assert not labels and not discs
        assert max(line.get_linewidth() for line in ax.lines) < 1.0


def test_chaos_legend_is_outside_the_data(tmp_path, figures):
    from truav.swarm.chaos import chaos_figure
    plan = tmp_path / "plan.toml"
    plan.write_text('[[fault]]\nkind = "crash"\nstart = 1.0\nuav = 1\n')

    def summary(dip: float) -> dict:
        return {"timeline": {"coverage": [[t, 20.0 - (dip if t > 10 else 0.0)] for t in range(50)],
                             "hovering": [[t, 0] for t in range(50)]}}

    chaos_figure(summary(0.0), summary(5.0), str(plan), 10.0, tmp_path / "chaos.png")
    fig = figures[-1]
    cov_ax = fig.axes[1]
    fig.canvas.draw()
    legend, plot_area = cov_ax.get_legend().get_window_extent(), cov_ax.get_window_extent()
    assert legend.y0 >= plot_area.y1 - 1  # above the curves, not over them


@pytest.mark.parametrize("n_seeds", [2, 3])
def test_few_seeds_draw_each_seed_not_a_band(tmp_path, figures, small_cfg, n_seeds):
    from matplotlib.collections import PathCollection, PolyCollection
    from truav.experiments import report, runner
    cells = [runner.Cell("patrol", v, tuple(range(n_seeds)), 2, 1) for v in (5.0, 25.0)]
    runner.run_cells(small_cfg, tmp_path, cells, workers=1)
    results = [runner.load_cell(runner.cell_path(tmp_path, small_cfg, c), c) for c in cells]
    rows = report.summary_rows(results, 1)
    report.write_summary_csv(tmp_path / "summary.csv", rows)
    assert "_eval_seed_values" not in (tmp_path / "summary.csv").read_text()
    report.versus_figure(rows, "speed_mps", "v", tmp_path / "v.png", "t")
    report.convergence_figure(results, tmp_path / "c.png", 1, "t")
    for fig in figures[-2:]:
        axes = [ax for ax in fig.axes if ax.has_data()]
        bands = [c for ax in axes for c in ax.collections if isinstance(c, PolyCollection)]
        assert bool(bands) == (n_seeds >= 3), fig
    seeds_drawn = [c for ax in figures[-2].axes for c in ax.collections if isinstance(c, PathCollection)]
    if n_seeds < 3:  # versus: each seed's value at each setting
        assert sum(len(c.get_offsets()) for c in seeds_drawn) == 4 * 2 * n_seeds  # panels x speeds x seeds
    else:
        assert not seeds_drawn


def test_training_energy_axis_shows_small_changes_small(tmp_path, figures):
    from truav.analysis.plots import convergence_figure
    rng = np.random.default_rng(0)
    energy = 22_250.0 + rng.normal(0, 20, (200, 1))  # +-0.1%: noise, not a trend
    convergence_figure({"energy_j": energy, "coverage_pct": rng.uniform(5, 30, (200, 1))}, tmp_path / "c.png",
                       window=20)
    ax = next(ax for ax in figures[-1].axes if "energy" in ax.get_ylabel())
    lo, hi = ax.get_ylim()
    assert hi - lo >= 0.05 * 22.25 - 1e-9 and lo <= 22.2 and hi >= 22.3


def test_scheme_comparison_keeps_coinciding_series_visible(tmp_path, figures):
    from truav.swarm.scheme_faults import metric_figure
    rows = [{"scheme": s, "kind": k, "level": x, "missed_actions": 0.0}  # every scheme on the same points
            for s in ("truav", "central", "patrol") for k in ("loss", "latency", "crash") for x in (0.0, 0.5)]
    metric_figure(rows, ("truav", "central", "patrol"), "missed_actions", "missed", 100.0, tmp_path / "m.png", "t")
    lines = figures[-1].axes[0].get_lines()
    assert len({(line.get_linestyle(), line.get_marker()) for line in lines}) == 3
    sizes = [line.get_markersize() for line in lines]  # the first drawn is the largest: it shows around the rest
    widths = [line.get_linewidth() for line in lines]
    assert sizes == sorted(sizes, reverse=True) and len(set(sizes)) == 3 and widths == sorted(widths, reverse=True)


def test_scheme_comparison_of_all_five_schemes_draws_every_series(tmp_path, figures):
    from truav.swarm.scheme_faults import SCHEMES, metric_figure
    rows = [{"scheme": s, "kind": k, "level": x, "coverage_pct": 20.0}  # every scheme on the same points
            for s in SCHEMES for k in ("loss", "latency", "crash") for x in (0.0, 0.5)]
    metric_figure(rows, SCHEMES, "coverage_pct", "coverage (%)", 1.0, tmp_path / "c.png", "t")
    lines = figures[-1].axes[0].get_lines()
    assert len(lines) == len(SCHEMES)
    assert all(line.get_markersize() >= 4 and line.get_linewidth() >= 0.8 for line in lines)
    assert len({(line.get_linestyle(), line.get_marker(), line.get_color()) for line in lines}) == len(SCHEMES)
    labels = [t.get_text() for t in figures[-1].axes[0].get_legend().get_texts()]
    assert labels == list(SCHEMES)


def _recording(n_uavs: int):
    from recorder.report import MapConfig, Recording, Series
    rng = np.random.default_rng(1)
    rec = Recording(first_ns=0, last_ns=60 * 10**9, config=MapConfig(5000.0, 500.0, [(1000.0, 1000.0)], [], 500.0))
    for u in range(n_uavs):
        start = rng.uniform(500, 4500, 2)
        steps = np.cumsum(rng.normal(0, 15, (60, 2)), axis=0)
        rec.beacons[u] = Series(log_ns=list(range(60)), pub_ns=list(range(60)), xy=[tuple(p) for p in start + steps])
    return rec


@pytest.mark.parametrize("n", [20, 100])
def test_recording_map_of_many_uavs_stays_readable(tmp_path, figures, n):
    from matplotlib.patches import Circle
    from recorder.report import map_figure
    from truav.analysis.swarm_plots import MAX_LABELLED_UAVS
    map_figure(_recording(n), tmp_path / "map.png")
    ax = figures[-1].axes[0]
    entries = [t.get_text() for t in ax.get_legend().get_texts()]
    per_uav = [e for e in entries if e.startswith("UAV ")]
    discs = [p for p in ax.patches if isinstance(p, Circle)]
    if n <= MAX_LABELLED_UAVS:
        assert len(per_uav) == n and len(discs) == n
    else:  # one legend line for all the tracks, not a hundred; no discs
        assert not per_uav and not discs and len(entries) <= 6

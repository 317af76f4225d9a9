"""Pictures whose title and legend fit inside them, whatever the number of columns."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402

from truav.experiments import report  # noqa: E402
from truav.experiments.cells import Cell, CellResult  # noqa: E402


def test_convergence_at_one_speed_keeps_its_title_and_legend_inside(tmp_path, monkeypatch):
    import matplotlib.pyplot as plt
    kept = []
    monkeypatch.setattr(plt, "close", lambda fig: kept.append(fig))
    rng = np.random.default_rng(0)
    metrics = {name: rng.uniform(0.1, 0.9, (6, 2)) for name, _, _ in report.PANELS}
    results = [CellResult(Cell(s, 15.0, (0, 1), 6, 1), metrics, metrics, 1.0) for s in ("truav", "patrol")]
    report.convergence_figure(results, tmp_path / "c.png", 2, "Training convergence (2-episode sliding window)")
    fig = kept[-1]
    fig.canvas.draw()
    page = fig.bbox
    texts = [fig._suptitle] + fig.legends
    for artist in texts:
        box = artist.get_window_extent()
        assert box.x0 >= page.x0 - 1 and box.x1 <= page.x1 + 1, (artist, box, page)
    assert fig.get_size_inches()[0] >= report.CONVERGENCE_MIN_WIDTH_IN


def test_the_missed_panel_claims_no_miss_only_when_the_world_counted_none(tmp_path, monkeypatch):
    import matplotlib.pyplot as plt
    from truav.analysis.swarm_plots import swarm_figure
    from truav.config import Config
    from truav.swarm.monitor import Monitor
    kept = []
    monkeypatch.setattr(plt, "close", lambda fig: kept.append(fig))
    cfg = Config().replace(scenario={"steps_per_episode": 20})
    m = Monitor(2, period_s=0.1)
    m.tracks = {0: [(100.0, 100.0), (110.0, 100.0)], 1: [(900.0, 900.0), (900.0, 910.0)]}
    m.coverage = [(t, 10.0) for t in range(30)]
    m.hovering = [(t, 0.0) for t in range(30)]  # the step metrics heard: none hovered
    texts = {}
    for missed in (0, 5, None):
        swarm_figure(cfg, m, tmp_path / f"s{missed}.png", episodes_done=1, missed=missed)
        texts[missed] = [t.get_text() for t in kept[-1].axes[2].texts]
    assert texts[0] == ["every UAV acted in time on every tick"]
    assert texts[5] == ["none in the step metrics heard, but the world\ncounted 5 missed action(s), on ticks not heard"]
    assert "every UAV acted in time" not in texts[None][0]


def test_metrics_png_names_the_worlds_per_uav_counts_as_a_reader_says_them():
    from recorder.report_figures import metric_label
    assert metric_label("uav.2.missed") == "UAV 2: actions missed (hovered), total so far"
    assert metric_label("uav.11.late") == "UAV 11: actions too late, total so far"
    assert metric_label("rejected") == "messages the world refused (total so far)"
    assert metric_label("rejected.too_large") == "messages the world refused as too large (total so far)"
    assert metric_label("some_new_metric") == "some new metric"

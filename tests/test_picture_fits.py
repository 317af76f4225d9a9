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

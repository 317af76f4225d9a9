"""Training and experiment cells split over forked worker processes give the numbers of one process
(the in-process parts: tests/unit/test_trainer.py, tests/unit/test_experiments.py)."""

import numpy as np

from truav.analysis.trainer import run_parallel
from truav.experiments import runner


def test_worker_processes_change_no_number(small_cfg):
    seeds = [1, 2, 3]
    one = run_parallel("truav", small_cfg, seeds, 2, workers=1)
    two = run_parallel("truav", small_cfg, seeds, 2, workers=2)
    for k in one.metrics:
        np.testing.assert_array_equal(one.metrics[k], two.metrics[k])
    np.testing.assert_array_equal(one.q, two.q)


def test_cells_are_worker_independent(tmp_path, small_cfg):
    cells = [runner.Cell("patrol", 15.0, (s,), 2, 1) for s in (0, 1)]
    runner.run_cells(small_cfg, tmp_path / "a", cells, workers=2)
    runner.run_cells(small_cfg, tmp_path / "b", cells, workers=1)
    for c in cells:
        a = runner.load_cell(runner.cell_path(tmp_path / "a", small_cfg, c), c)
        b = runner.load_cell(runner.cell_path(tmp_path / "b", small_cfg, c), c)
        for k in a.train:
            np.testing.assert_array_equal(a.train[k], b.train[k])

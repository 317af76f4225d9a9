"""The experiment runner: cells resume, tidy CSV shape, and the CLI end to end (--quick); cells on worker
processes: tests/swarm/test_worker_processes.py."""

import csv

import numpy as np

from truav.cli.main import main
from truav.experiments import runner


def _rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_resume_skips_finished_cells(tmp_path, small_cfg):
    cells = [runner.Cell("patrol", v, (0, 1), 2, 1) for v in (5.0, 25.0)]
    ran = []
    runner.run_cells(small_cfg, tmp_path, cells, workers=1, on_cell=lambda c, w: ran.append(c))
    assert ran == sorted(cells, key=lambda c: -c.speed)
    assert all(runner.cell_path(tmp_path, small_cfg, c).is_file() for c in cells)
    saved = runner.load_cell(runner.cell_path(tmp_path, small_cfg, cells[0]), cells[0])
    assert saved.train["coverage_pct"].shape == (2, 2) and saved.eval["coverage_pct"].shape == (1, 2)
    ran.clear()
    runner.run_cells(small_cfg, tmp_path, cells, workers=1, on_cell=lambda c, w: ran.append(c))
    assert ran == []  # nothing left to do
    runner.cell_path(tmp_path, small_cfg, cells[1]).unlink()
    runner.run_cells(small_cfg, tmp_path, cells, workers=1, on_cell=lambda c, w: ran.append(c))
    assert ran == [cells[1]]  # only the missing cell
    # a cell's key follows its inputs, but not config sections its scheme never reads
    other = small_cfg.replace(traffic={"packet_rate_hz": 0.3})
    assert cells[0].key(other) != cells[0].key(small_cfg)
    assert cells[0].key(small_cfg.replace(central={"hidden": 32})) == cells[0].key(small_cfg)


def test_cli_velocity_quick_end_to_end(tmp_path, capsys):
    schemes = ["truav", "patrol"] + (["central"] if _has_torch() else [])
    out = tmp_path / "v"
    args = ["experiment", "velocity", "--quick", "--out", str(out), "--quiet", "--workers", "1",
            "--schemes", *schemes, "--speeds", "5", "25"]
    assert main(args) == 0
    for name in ("velocity.csv", "summary.csv", "summary.md", "velocity.png", "convergence.png", "config.toml"):
        assert (out / name).is_file(), name
    rows = _rows(out / "velocity.csv")
    # 6 episodes in windows of 3 -> 2 training rows + 1 eval row, per scheme x speed x seed
    assert len(rows) == len(schemes) * 2 * 2 * 3
    assert {r["phase"] for r in rows} == {"train", "eval"}
    assert {float(r["speed_mps"]) for r in rows} == {5.0, 25.0}
    summary = _rows(out / "summary.csv")
    assert len(summary) == len(schemes) * 2 and all(r["eval_coverage_pct_mean"] for r in summary)
    if "central" in schemes:
        central = [r for r in rows if r["scheme"] == "central"]
        assert all(float(r["ctrl_up_msgs"]) == 5 * 20 for r in central)  # U x steps per episode
    capsys.readouterr()
    assert main(args) == 0  # resumed: nothing to run
    assert "0 to run" in capsys.readouterr().out


def test_cli_scale_quick(tmp_path, capsys):
    schemes = ["truav"] + (["central"] if _has_torch() else [])
    out = tmp_path / "s"
    assert main(["experiment", "scale", "--quick", "--out", str(out), "--quiet", "--workers", "1",
                 "--seeds", "1", "--schemes", *schemes]) == 0
    text = (out / "summary.md").read_text()
    assert "Control-plane traffic per second" in text
    rows = _rows(out / "scale.csv")
    assert {(int(r["n_uavs"]), int(r["n_vehicles"])) for r in rows} == {(2, 30), (4, 30), (2, 60), (4, 60)}
    assert (out / "scale.png").is_file()


def test_cli_experiment_mistakes(tmp_path, capsys):
    assert main(["experiment", "velocity", "--quick", "--out", str(tmp_path), "--episodes-for", "nope=3"]) == 2
    assert "--episodes-for" in capsys.readouterr().err
    assert main(["experiment", "velocity", "--report-only", "--quick", "--out", str(tmp_path / "empty")]) == 2
    assert "no finished cells" in capsys.readouterr().err


def _has_torch():
    try:
        import torch  # noqa: F401
        return True
    except ImportError:
        return False

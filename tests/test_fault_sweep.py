"""`truav experiment faults` end to end on a tiny size: real swarm runs, CSV, figure, resume."""

import csv

from truav.experiments import faults as fault_sweep
from truav.config import Config


def test_tiny_sweep_writes_csv_and_figure_and_resumes(tmp_path, monkeypatch):
    monkeypatch.setitem(fault_sweep.SIZES, "tiny", fault_sweep.SweepSize((0.0, 0.5), (0.0, 300.0), 1, 12, 2))
    cfg = Config().replace(scenario={"n_vehicles": 40, "n_uavs": 3}, roads={"warmup_steps": 5})
    out = tmp_path / "sweep"
    png = fault_sweep.run_sweep(cfg, "tiny", out, rate_hz=20.0)
    assert png.is_file()
    rows = list(csv.DictReader(open(out / "faults.csv")))
    assert [(r["kind"], float(r["level"])) for r in rows] == [("loss", 0.0), ("loss", 0.5), ("latency", 0.0),
                                                              ("latency", 300.0)]
    assert all(0.0 <= float(r["coverage_pct"]) <= 100.0 for r in rows)
    # the loss plan really dropped beacons at the agents
    import json
    agents = json.loads((out / "loss-0.5" / "summary.json").read_text())["agents"]
    assert sum(a["bus"]["filtered"] for a in agents if a) > 0
    # a second call reuses the finished points (no new swarm run)
    stamp = (out / "loss-0.5" / "summary.json").stat().st_mtime
    fault_sweep.run_sweep(cfg, "tiny", out, rate_hz=20.0, qtable=str(out / "policy"))
    assert (out / "loss-0.5" / "summary.json").stat().st_mtime == stamp

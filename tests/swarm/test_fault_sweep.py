"""`truav experiment faults` end to end on a tiny size: real swarm runs, CSV, figure, resume."""

import csv
import json

from agents.process.agent_process import DELAY_ENV
from truav.config import Config
from truav.swarm import fault_sweep


def test_tiny_sweep_writes_csv_and_figure_and_resumes(tmp_path, monkeypatch, capsys):
    """Real time: on a busy host agents miss actions. The sweep still finishes (it once stopped at
    "58% of the actions were missing"), and says which points missed how much. Two of the three
    agents are made slow here, so every point misses more than half of its actions, as on a loaded machine."""
    monkeypatch.setitem(fault_sweep.SIZES, "tiny", fault_sweep.SweepSize((0.0, 0.5), (0.0, 300.0), 1, 12, 2))
    monkeypatch.setenv(DELAY_ENV, "0:200,1:200")  # inherited by the agent processes: 4 periods per observation
    cfg = Config().replace(scenario={"n_vehicles": 40, "n_uavs": 3}, roads={"warmup_steps": 5})
    out = tmp_path / "sweep"
    png = fault_sweep.run_sweep(cfg, "tiny", out, rate_hz=20.0)
    assert png.is_file()
    rows = list(csv.DictReader(open(out / "faults.csv")))
    assert [(r["kind"], float(r["level"])) for r in rows] == [("loss", 0.0), ("loss", 0.5), ("latency", 0.0),
                                                              ("latency", 300.0)]
    assert all(0.0 <= float(r["coverage_pct"]) <= 100.0 for r in rows)
    # honest about what real time missed: in the CSV and in a warning per point
    assert all(int(r["missed_actions"]) > 0 for r in rows)
    printed = capsys.readouterr().out
    for kind, level in (("loss", "0"), ("loss", "0.5"), ("latency", "0"), ("latency", "300")):
        assert f"warning: point {kind} {level} missed" in printed, printed
    # the loss plan really dropped beacons at the agents
    agents = json.loads((out / "loss-0.5" / "summary.json").read_text())["agents"]
    assert sum(a["bus"]["filtered"] for a in agents if a) > 0
    # a second call reuses the finished points (no new swarm run)
    stamp = (out / "loss-0.5" / "summary.json").stat().st_mtime
    fault_sweep.run_sweep(cfg, "tiny", out, rate_hz=20.0, qtable=str(out / "policy"))
    assert (out / "loss-0.5" / "summary.json").stat().st_mtime == stamp

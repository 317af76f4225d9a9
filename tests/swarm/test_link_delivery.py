"""Issue 45: a swarm run with 30% beacon loss at the receivers: each agent counts what it heard per sender
(health reports, stats file) and `truav report`'s links.png shows about 70% delivered on every link."""

from __future__ import annotations

import json

import numpy as np

from recorder.report import LINKS_FILE, load_recording, report
from recorder.report_links import link_delivery
from tests.support.runs import up_to_end
from tests.support.swarm_up import SMALL
from truav.config import Config

PLAN = """seed = 1
[[fault]]
kind = "loss"
start = 0.0
probability = 0.3
keys = "uav/*/beacon"
"""


def test_receiver_side_beacon_loss_is_counted_by_the_agents_and_shown_per_link(tmp_path) -> None:
    plan = tmp_path / "loss.toml"
    plan.write_text(PLAN)
    rec = tmp_path / "run.mcap"
    out = up_to_end(tmp_path, "links", Config(), "--episodes", "1", "--steps", "60", "--fault-plan", str(plan),
                    "--max-missed", "1",  # real time: a busy host's missed actions are not what this test is about
                    "--record", str(rec), *SMALL)
    links = link_delivery(load_recording(rec))
    assert links is not None and links.receivers.all(), "every agent reported what it heard"
    off = ~np.eye(len(links.heard), dtype=bool)
    overall = links.heard[off].sum() / links.sent[off].sum()
    assert 0.6 < overall < 0.8, overall  # 30% lost at the receivers (~1,200 beacons: +-3% is 2.5 sigma)
    assert np.nanmax(links.share) < 0.95
    stats = json.loads((out / "agent0.json").read_text())
    heard = stats["beacons_heard"]
    assert heard[0] == 0 and 0.6 * stats["steps"] < np.mean(heard[1:]) < 0.8 * stats["steps"] + 2, heard
    report_dir, lines = report(rec, tmp_path / "rep")
    assert (report_dir / LINKS_FILE).is_file(), lines
    # the run's numbers end with a scale: hover and patrol on the same scenario, seed and episode count
    refs = json.loads((out / "summary.json").read_text())["references"]
    assert refs["seed"] == 0 and refs["episodes"] == 1 and set(refs) >= {"hover", "patrol"}
    assert "references on the same scenario, seed 0, 1 episode, without the faults" in \
        (tmp_path / "links.log").read_text()

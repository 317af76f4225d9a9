"""Every fault kind on a small real swarm, under the supervisor, bounded in time."""

import json

from recorder.check import check
from truav.config import Config
from truav.swarm.supervisor import SwarmOptions, run_swarm

PLAN = """
seed = 3
[[fault]]
kind = "loss"
start = 0.5
duration = 3.0
probability = 0.5
keys = "uav/*/beacon"
[[fault]]
kind = "latency"
start = 1.0
duration = 3.0
fixed_ms = 120.0
jitter_ms = 30.0
keys = "uav/*/beacon"
[[fault]]
kind = "partition"
start = 2.0
duration = 2.0
groups = [[0, 1], [2, 3]]
[[fault]]
kind = "obs_loss"
start = 3.0
duration = 2.0
probability = 0.5
uavs = [0]
[[fault]]
kind = "crash"
start = 1.5
uav = 2
restart_after = 2.0
[[fault]]
kind = "freeze"
start = 4.0
duration = 1.0
uav = 3
"""


def test_every_fault_kind_on_a_live_swarm(tmp_path):
    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN)
    cfg = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": 40, "n_uavs": 4},
                           roads={"warmup_steps": 10})
    out = tmp_path / "swarm"
    mcap = tmp_path / "chaos.mcap"
    rc = run_swarm(cfg, SwarmOptions(run="chaos", episodes=2, out=str(out), plot=False, quiet=True,
                                     fault_plan=str(plan), verbose=True, checkpoint_every=5, record=str(mcap),
                                     # a busy host makes real-time agents miss actions: reported below,
                                     # not a failed run
                                     max_missed_share=1.0))
    assert rc == 0
    summary = json.loads((out / "summary.json").read_text())
    world = summary["world"]
    # the world never stalled: every tick ran, none waited for the frozen (1 s) or crashed agent (a busy
    # host starts ticks tens of milliseconds late)
    assert world["ticks"] == 2 * 41
    assert world["tick_lateness_ms"]["p99"] < 500.0
    # every action the world waited for is counted, received or missed (the crashed and frozen agents')
    assert world["actions_received"] + world["deadline_misses"] == 4 * 80 and world["deadline_misses"] > 0
    # agent 1, never crashed, frozen or cut off from its observations, kept acting
    agent1 = summary["agents"][1]
    assert agent1["steps"] + agent1["stale_obs_skipped"] >= 40, agent1
    assert any("uav/2" in k for k in world["losses"])
    # the crashed agent came back from its checkpoint
    log = (out / "logs" / "agent2.log").read_text()
    assert "resumed from checkpoint" in log
    # every fault start and end was published
    events = {(kind, phase) for _, kind, phase in summary["fault_events"]}
    for kind in ("loss", "latency", "partition", "obs_loss", "crash", "freeze"):
        assert (kind, "start") in events and (kind, "end") in events, kind
    # link faults reached the agents' transports
    filtered = sum(a["bus"]["filtered"] for a in summary["agents"] if a)
    delayed = sum(a["bus"]["delayed"] for a in summary["agents"] if a)
    assert filtered > 0 and delayed > 0
    # the recorder (which no plan filters) holds every message that was sent: no sequence gaps,
    # and each fault's start and end
    report = check(str(mcap))
    assert report.finished and report.missing == 0, report.format_report()
    for kind in ("loss", "latency", "partition", "obs_loss", "crash", "freeze"):
        assert report.channels[f"truav/chaos/fault/{kind}"].messages == 2

"""Per-UAV accounting in world.json, the silent-agent rule and a hand-started world's --max-missed exit code,
from real small lock-step runs: a hand-started router and world, UAV 0 flown by examples/outside_agent.py and
UAV 1 by a stub written here (zenoh and msgpack only) that holds its liveliness token and answers nothing,
or answers with an out-of-range action. Loopback only; every process started is stopped, bounded in time."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from tests.conftest import free_port
from tests.test_outside_agent import CLI, EXAMPLE, Swarm
from truav.config import Config, to_toml
from world.world_stats import UavAccounts

RUN = "acct"
N_UAVS, STEPS, EPISODES, WAIT_S = 2, 10, 2, 1.0
CFG = Config().replace(scenario={"n_vehicles": 40, "steps_per_episode": STEPS, "n_uavs": N_UAVS},
                       roads={"warmup_steps": 5})
STUB = '''
import json, sys, time, msgpack, zenoh
ep, run, me, mode = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("scouting/multicast/enabled", "false")
conf.insert_json5("connect/endpoints", json.dumps([ep]))
s = zenoh.open(conf)
base, seq, stop = f"truav/{run}", [0], []
def on_obs(sample):
    if mode == "silent":
        return
    obs = msgpack.unpackb(sample.payload.to_bytes())
    action = 99 if obs["tick"] == 3 else 0  # mode bad: one action out of range
    s.put(f"{base}/uav/{me}/action", msgpack.packb({"v": 1, "kind": "action", "src": f"uav/{me}", "seq": seq[0],
          "t": time.time_ns(), "inc": 7, "uav": me, "tick": obs["tick"], "action": action}))
    seq[0] += 1
sub = s.declare_subscriber(f"{base}/uav/{me}/obs", on_obs)
ctl = s.declare_subscriber(f"{base}/control/shutdown", lambda sample: stop.append(1))
tok = s.liveliness().declare_token(f"{base}/alive/uav/{me}")
end = time.monotonic() + 240
while not stop and time.monotonic() < end:
    time.sleep(0.05)
tok.undeclare(); sub.undeclare(); ctl.undeclare(); s.close()
'''


def run_swarm(d: Path, mode: str, max_missed: float) -> tuple[int, dict, str, float]:
    """(world's exit code, world.json, world's log, seconds from the world's first tick to its exit)."""
    (d / "scenario.toml").write_text(to_toml(CFG))
    (d / "stub.py").write_text(STUB)
    ep = f"tcp/127.0.0.1:{free_port()}"
    sw = Swarm(d)
    try:
        sw.start("router", [*CLI, "router", "-l", ep])
        sw.wait_log("router", "router listening", 60)
        world = sw.start("world", [*CLI, "world", "--run", RUN, "--scenario", "scenario.toml", "-e", ep,
                                   "--episodes", str(EPISODES), "--lockstep", "--lockstep-wait", str(WAIT_S),
                                   "--max-missed", str(max_missed), "--stats-out", "world.json",
                                   "--wait-agents", "120"])
        sw.start("uav0", [sys.executable, str(EXAMPLE), "--id", "0", "--run", RUN, "--lockstep", "-e", ep])
        sw.start("uav1", [sys.executable, "stub.py", ep, RUN, "1", mode])
        sw.wait_log("world", "starting lock-step", 180)
        t0 = time.monotonic()
        code = world.wait(timeout=240)
        took = time.monotonic() - t0
        return code, json.loads((d / "world.json").read_text()), sw.log("world"), took
    finally:
        sw.close()


def check_totals(w: dict) -> None:
    per = w["per_uav"]
    assert [u["uav"] for u in per] == list(range(N_UAVS))
    assert sum(u["applied"] for u in per) == w["actions_received"]
    assert sum(u["late"] for u in per) == w["late_actions"]
    assert sum(u["stale"] for u in per) == w["stale_actions"]
    assert sum(u["missed"] for u in per) == w["deadline_misses"] + w["acks_missed"]
    for u in per:
        assert u["received"] == u["applied"] + u["late"] + u["stale"]
        assert u["rejected"] == {r: s[f"uav/{u['uav']}"] for r, s in w["rejected"].items() if f"uav/{u['uav']}" in s}


def test_silent_agent_costs_one_wait_and_fails_past_max_missed(tmp_path):
    code, w, log, took = run_swarm(tmp_path, "silent", 0.4)
    check_totals(w)
    ticks = EPISODES * (STEPS + 1)
    assert w["ticks"] == ticks
    silent = w["per_uav"][1]
    assert silent["missed"] == ticks and silent["applied"] == 0  # every action and `done` acknowledgement
    assert w["per_uav"][0]["missed"] == 0 and w["per_uav"][0]["applied"] == EPISODES * STEPS
    assert w["silent_marked"] == 1 and w["silent_at_end"] == [1]
    assert log.count("marked silent") == 1
    assert "no action in time from uav 1" in log
    assert took < ticks * WAIT_S  # waited once, not on every tick
    assert code == 1 and "more than --max-missed 0.4" in log  # 50% missing


def test_out_of_range_action_in_its_uavs_rejected_and_exit_0_below_max_missed(tmp_path):
    code, w, log, _ = run_swarm(tmp_path, "bad", 0.5)
    check_totals(w)
    bad = w["per_uav"][1]
    assert bad["rejected"].get("out_of_range", 0) >= 1 and w["per_uav"][0]["rejected"] == {}
    # the refused tick is missed; marked silent, its next answer may also come after that round closed
    assert bad["missed"] >= 1 and EPISODES * STEPS - 3 <= bad["applied"] <= EPISODES * STEPS - 1
    assert code == 0, log[-2000:]


def test_worst_metrics_bounded():
    acc = UavAccounts(1000)
    for i in range(0, 1000, 2):
        acc.missed[i] = i
    values = acc.worst_metrics({"out_of_range": {"uav/3": 5, "router": 1}}, limit=20)
    assert len(values) <= 4 * 20 and values["uav.998.missed"] == 998 and "uav.0.missed" not in values
    assert acc.per_uav({"out_of_range": {"uav/3": 5}})[3]["rejected"] == {"out_of_range": 5}

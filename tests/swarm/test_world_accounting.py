"""Per-UAV accounting in world.json, the silent-agent rule and a hand-started world's --max-missed exit code,
from real small lock-step runs: a hand-started router and world, UAV 0 flown by examples/outside_agent.py and
UAV 1 by a stub written here (zenoh and msgpack only) that holds its liveliness token and answers nothing,
or answers with an out-of-range action. Loopback only; every process started is stopped, bounded in time."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.support.waits import free_port
from tests.support.outside import CLI, EXAMPLE, Swarm
from truav.config import Config, to_toml
from world.world_stats import UavAccounts

RUN = "acct"
N_UAVS, STEPS, EPISODES, WAIT_S = 2, 10, 2, 1.0
FLOOD = 500  # bad actions the flooding stub sends in one burst
CFG = Config().replace(scenario={"n_vehicles": 40, "steps_per_episode": STEPS, "n_uavs": N_UAVS},
                       roads={"warmup_steps": 5})
STUB = '''
import json, sys, time, msgpack, zenoh
FLOOD = int(sys.argv[5]) if len(sys.argv) > 5 else 0
ep, run, me, mode = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
conf = zenoh.Config.from_file(ep) if ep.endswith(".json5") else zenoh.Config()  # --secure: its credentials
conf.insert_json5("mode", '"client"')
conf.insert_json5("scouting/multicast/enabled", "false")
if not ep.endswith(".json5"):
    conf.insert_json5("connect/endpoints", json.dumps([ep]))
s = zenoh.open(conf)
base, seq, stop = f"truav/{run}", [0], []
told = open("rejections.jsonl", "w")
def put_action(tick, action):
    s.put(f"{base}/uav/{me}/action", msgpack.packb({"v": 1, "kind": "action", "src": f"uav/{me}", "seq": seq[0],
          "t": time.time_ns(), "inc": 7, "uav": me, "tick": tick, "action": action}))
    seq[0] += 1
def on_obs(sample):
    if mode == "silent":
        return
    obs = msgpack.unpackb(sample.payload.to_bytes())
    if obs["tick"] == 3:  # mode bad: one action out of range; flood: FLOOD of them, then a valid one
        for _ in range(FLOOD if mode == "flood" else 1):
            put_action(3, 99)
        if mode == "bad":
            return
    put_action(obs["tick"], 0)
def on_rejected(sample):  # what the world tells this UAV it refused
    told.write(json.dumps(msgpack.unpackb(sample.payload.to_bytes())) + "\\n")
    told.flush()
sub = s.declare_subscriber(f"{base}/uav/{me}/obs", on_obs)
rej = s.declare_subscriber(f"{base}/uav/{me}/rejected", on_rejected)
ctl = s.declare_subscriber(f"{base}/control/shutdown", lambda sample: stop.append(1))
tok = s.liveliness().declare_token(f"{base}/alive/uav/{me}")
end = time.monotonic() + 240
while not stop and time.monotonic() < end:
    time.sleep(0.05)
tok.undeclare(); sub.undeclare(); rej.undeclare(); ctl.undeclare(); s.close()
'''


def run_swarm(d: Path, mode: str, max_missed: float, secure: bool = False,
              flood: int = 0) -> tuple[int, dict, str, float, list[dict]]:
    """(world's exit code, world.json, world's log, seconds from the world's first tick to its exit, the
    rejections the stub (UAV 1) received)."""
    (d / "scenario.toml").write_text(to_toml(CFG))
    (d / "stub.py").write_text(STUB)
    ep = f"tcp/127.0.0.1:{free_port()}"
    sw = Swarm(d)
    try:
        if secure:
            subprocess.run([*CLI, "certs", "--out", str(d / "creds"), "--run", RUN, "--agents", str(N_UAVS),
                            "-e", ep], check=True, capture_output=True, timeout=60)
            link, example, stub = (["--creds", "creds"], ["-c", str(d / "creds" / "uav-0.json5")],
                                   str(d / "creds" / "uav-1.json5"))
        else:
            link, example, stub = ["-e", ep], ["-e", ep], ep
        sw.start("router", [*CLI, "router", *(link if secure else ["-l", ep])])
        sw.wait_log("router", "router listening", 60)
        world = sw.start("world", [*CLI, "world", "--run", RUN, "--scenario", "scenario.toml", *link,
                                   "--episodes", str(EPISODES), "--lockstep", "--lockstep-wait", str(WAIT_S),
                                   "--max-missed", str(max_missed), "--stats-out", "world.json",
                                   "--wait-agents", "120"])
        sw.start("uav0", [sys.executable, str(EXAMPLE), "--id", "0", "--run", RUN, "--lockstep", *example])
        sw.start("uav1", [sys.executable, "stub.py", stub, RUN, "1", mode, str(flood)])
        sw.wait_log("world", "starting lock-step", 180)
        t0 = time.monotonic()
        code = world.wait(timeout=240)
        took = time.monotonic() - t0
        sw.procs["uav1"].wait(timeout=30)  # it exits on the world's shutdown: its file is complete
        told = [json.loads(line) for line in (d / "rejections.jsonl").read_text().splitlines()]
        return code, json.loads((d / "world.json").read_text()), sw.log("world"), took, told
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
    code, w, log, took, _ = run_swarm(tmp_path, "silent", 0.4)
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


@pytest.mark.parametrize("secure", [False, True], ids=["plain", "secure"])
def test_out_of_range_action_in_its_uavs_rejected_told_to_it_and_exit_0_below_max_missed(tmp_path, secure):
    code, w, log, _, told = run_swarm(tmp_path, "bad", 0.5, secure=secure)
    check_totals(w)
    bad = w["per_uav"][1]
    assert bad["rejected"].get("out_of_range", 0) >= 1 and w["per_uav"][0]["rejected"] == {}
    # the refused tick is missed; marked silent, its next answer may also come after that round closed
    assert bad["missed"] >= 1 and EPISODES * STEPS - 3 <= bad["applied"] <= EPISODES * STEPS - 1
    assert code == 0, log[-2000:]
    # The sender was told, on its own key: the reason, the key and kind, the tick, what was wrong.
    first = told[0]
    assert (first["kind"], first["src"], first["uav"], first["reason"]) == ("rejection", "world", 1, "out_of_range")
    assert first["key"] == f"truav/{RUN}/uav/1/action" and first["refused_kind"] == "action"
    assert first["at_tick"] == 3 and "99" in first["detail"] and first["counts"] == {"out_of_range": 1}
    # Each refusal told once (a late answer after the silent mark, if any, as late_action); world.json agrees.
    summed: dict[str, int] = {}
    for r in told:
        for reason, n in r["counts"].items():
            summed[reason] = summed.get(reason, 0) + n
    assert summed["out_of_range"] == bad["rejected"]["out_of_range"]
    assert summed.get("late_action", 0) == bad["late"] and summed.get("stale_action", 0) == bad["stale"]
    assert w["rejections_sent"] == len(told)


def test_a_flood_of_bad_actions_gets_bounded_rejections(tmp_path):
    """FLOOD out-of-range actions in one burst: all counted and told, in a few rejections, not one each."""
    code, w, log, _, told = run_swarm(tmp_path, "flood", 0.5, flood=FLOOD)
    check_totals(w)
    refused = w["per_uav"][1]["rejected"]["out_of_range"]
    assert refused == FLOOD, refused  # lock-step: the world's receive queue loses nothing
    assert sum(r["counts"].get("out_of_range", 0) for r in told) == FLOOD
    assert 1 <= len(told) <= FLOOD // 10, len(told)  # at most one per UAV per 100 ms, however many came
    assert w["per_uav"][1]["applied"] == EPISODES * STEPS  # the valid action after the burst was applied
    assert code == 0, log[-2000:]


def test_worst_metrics_bounded():
    acc = UavAccounts(1000)
    for i in range(0, 1000, 2):
        acc.missed[i] = i
    for _ in range(5):
        acc.note_refused(3, "out_of_range")
    acc.note_refused(1000, "out_of_range")  # no such UAV: not counted
    values = acc.worst_metrics(limit=20)
    assert len(values) <= 4 * 20 and values["uav.998.missed"] == 998 and "uav.0.missed" not in values
    assert acc.per_uav()[3]["rejected"] == {"out_of_range": 5} and acc.refused_total == 5


def test_refusals_are_counted_for_the_uav_of_their_key_not_of_the_payload(bus_factory):
    """A plain session's forgeries on uav/1's action key (another UAV's id and sender in the payload, the
    world's sender, bytes that are no message at all): counted for UAV 1, as the rejection it is told,
    never against UAV 0, whose name the payload borrowed."""
    from truav.wire import keys, schema
    from world.process.world_process import WorldNode, WorldOptions
    bus = bus_factory("world")
    node = WorldNode(CFG, WorldOptions(run=RUN), bus)
    key = keys.uav_action(RUN, 1)
    as_uav0 = schema.encode(schema.Sequencer("uav/0").stamp(schema.Action(uav=0, tick=0, action=3)))
    as_world = schema.encode(schema.Sequencer("world").stamp(schema.Action(uav=1, tick=0, action=3)))
    for raw in (as_uav0, as_world, b"\xffgarbage"):
        assert bus._decode(key, raw) is None
    per = node.accounts.per_uav()
    assert per[0]["rejected"] == {} and sum(per[1]["rejected"].values()) == 3, per
    assert set(node.accounts.worst_metrics()) == {"uav.1.rejected"}
    assert [n.uav for n in node.notices.due(1e9)] == [1]


def test_a_liveliness_token_of_a_uav_outside_the_scenario_is_refused_not_waited_for(bus_factory):
    """An agent started with --id 7 beside a 2-UAV world (or a plain session's forged token): counted as
    refused and ignored. It was taken for a live agent: tick 0 came with one real agent missing, lock-step
    waited for it, and the world crashed (IndexError) accounting its missed `done` acknowledgement."""
    from truav.wire import guard, keys
    from world.process.world_process import WorldNode, WorldOptions
    bus = bus_factory("world")
    node = WorldNode(CFG, WorldOptions(run=RUN, wait_agents_s=0.1), bus)
    for uav in (7, N_UAVS):
        node._on_join(keys.alive_uav(RUN, uav))
        node._on_leave(keys.alive_uav(RUN, uav))
        node._on_join(keys.alive_uav(RUN, uav))
    node._on_join(keys.alive_uav(RUN, 0))
    assert node.wait_for_agents() == 1 and node._alive == {0}
    assert bus.rejections.as_dict() == {guard.R_IMPLAUSIBLE: {"uav/7": 3, f"uav/{N_UAVS}": 3}}
    assert node.stats.joins == [keys.alive_uav(RUN, 0)] and node.stats.losses == []

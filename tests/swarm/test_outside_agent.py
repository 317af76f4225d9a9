"""examples/outside_agent.py (zenoh and msgpack only, no import of this project) flies UAV 2 of a 3-UAV
swarm started by hand (router, world, two project agents), in lock-step, in real time and under
--secure: every one of its actions applied (none missed, late or refused), and in lock-step the run is
reproducible (two runs of the same mixed swarm: equal Q-tables for the project's agents).

Loopback only; every process this test starts is stopped at its end, bounded in time."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tests.support.outside import CLI, EXAMPLE, Swarm
from tests.support.waits import free_port
from truav.config import Config, to_toml

RUN = "outside"
N_UAVS, OUTSIDE, EPISODES, STEPS = 3, 2, 3, 10
CFG = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": STEPS, "n_uavs": N_UAVS},
                       roads={"warmup_steps": 10}, learner={"episodes": EPISODES})
RATE_HZ = 5.0  # real time: a 160 ms deadline, room for a busy machine
START_TIMEOUT_S = 60.0
RUN_TIMEOUT_S = 240.0


def fly(d: Path, *, lockstep: bool, secure: bool) -> dict:
    """One run of the mixed swarm in ``d``: the world's stats, the example's output, the agents' Q-tables."""
    d.mkdir(parents=True)
    (d / "scenario.toml").write_text(to_toml(CFG))
    ep = f"tcp/127.0.0.1:{free_port()}"
    sw = Swarm(d)
    try:
        if secure:
            subprocess.run([*CLI, "certs", "--out", str(d / "creds"), "--run", RUN, "--agents", str(N_UAVS),
                            "-e", ep], check=True, capture_output=True, timeout=60)
            link = ["--creds", str(d / "creds")]
            example_link = ["-c", str(d / "creds" / f"uav-{OUTSIDE}.json5")]  # its identity's own config
        else:
            link = example_link = ["-e", ep]
        sw.start("router", [*CLI, "router", *(link if secure else ["-l", ep])])
        sw.wait_log("router", "router listening on", START_TIMEOUT_S)
        mode = ["--lockstep"] if lockstep else []
        common = ["--run", RUN, "--seed", "0", "--scenario", "scenario.toml", *mode, *link]
        sw.start("world", [*CLI, "world", *common, "--episodes", str(EPISODES), "--stats-out", "world.json",
                           "--rate", str(RATE_HZ), "--wait-agents", str(START_TIMEOUT_S * 2)])
        for i in range(N_UAVS):
            if i != OUTSIDE:
                sw.start(f"agent{i}", [*CLI, "agent", *common, "--id", str(i), "--rate", str(RATE_HZ),
                                       "--checkpoint", f"agent{i}.npz"])
        sw.start("example", [sys.executable, str(EXAMPLE), "--id", str(OUTSIDE), "--run", RUN, "--seed", "7",
                             "--timeout", str(RUN_TIMEOUT_S), *mode, *example_link])
        world = sw.procs["world"]
        assert world.wait(timeout=RUN_TIMEOUT_S) == 0, sw.log("world")[-3000:]
        for name, proc in sw.procs.items():
            if name != "router":
                assert proc.wait(timeout=30) == 0, (name, sw.log(name)[-3000:])
        out = {"world": json.loads((d / "world.json").read_text()), "example": sw.log("example"),
               "logs": {name: sw.log(name) for name in sw.procs}}
        for i in range(N_UAVS):
            if i != OUTSIDE:
                with np.load(d / f"agent{i}.npz") as ck:
                    out[f"q{i}"] = ck["q"].copy()
        return out
    finally:
        sw.close()


def check_every_action_applied(out: dict, lockstep: bool) -> None:
    w = out["world"]
    acting_ticks = EPISODES * STEPS
    assert w["ticks"] == EPISODES * (STEPS + 1)  # each episode's `done` observation is a tick too
    # Every UAV's action came in time and was applied, the example's included.
    assert w["actions_received"] == N_UAVS * acting_ticks, w
    assert w["deadline_misses"] == 0 and w["late_actions"] == 0 and w["stale_actions"] == 0, w
    assert w["lockstep_missed"] == 0, w
    refused = {reason: senders for reason, senders in w["rejected"].items() if f"uav/{OUTSIDE}" in senders}
    assert refused == {}, refused
    assert f"uav {OUTSIDE}: answered {acting_ticks} observations" in out["example"], out["example"]
    if lockstep:  # the project's agents never decided without the example's beacon
        for i in range(N_UAVS):
            if i != OUTSIDE:
                assert "no beacon from live peer" not in out["logs"][f"agent{i}"], out["logs"][f"agent{i}"][-2000:]


def test_example_uses_only_zenoh_and_msgpack() -> None:
    import ast
    tree = ast.parse(EXAMPLE.read_text())
    imported = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    imported |= {n.module.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
    third_party = imported - set(sys.stdlib_module_names)
    assert third_party == {"zenoh", "msgpack"}, third_party
    assert len(EXAMPLE.read_text().splitlines()) <= 130


@pytest.mark.parametrize("args", [["--id", "-1"], ["--id", "0", "-e", "PORT"], ["--id", "0", "-e", "garbage"],
                                  ["--id", "0", "-c", "nowhere.json5"]], ids=["id", "no-router", "endpoint", "config"])
def test_example_mistakes_are_an_error_line_not_a_traceback(tmp_path, args) -> None:
    """Started before the swarm's router, or with a mistyped endpoint or config: argparse's error, exit 2."""
    args = [f"tcp/127.0.0.1:{free_port()}" if a == "PORT" else a for a in args]
    done = subprocess.run([sys.executable, str(EXAMPLE), *args, "--timeout", "5"], capture_output=True, text=True,
                          cwd=tmp_path, timeout=60)
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert done.stderr.strip().splitlines()[-1].startswith("outside_agent.py: error: "), done.stderr


def test_outside_agent_flies_in_lockstep_reproducibly(tmp_path) -> None:
    first = fly(tmp_path / "first", lockstep=True, secure=False)
    check_every_action_applied(first, lockstep=True)
    second = fly(tmp_path / "second", lockstep=True, secure=False)
    check_every_action_applied(second, lockstep=True)
    for i in range(N_UAVS):
        if i != OUTSIDE:
            assert np.array_equal(first[f"q{i}"], second[f"q{i}"]), f"agent {i}: Q-tables differ between runs"
    assert first["world"]["actions_digest"] == second["world"]["actions_digest"]
    assert first["world"]["episodes"] == second["world"]["episodes"]


def test_outside_agent_flies_in_real_time(tmp_path) -> None:
    check_every_action_applied(fly(tmp_path / "rt", lockstep=False, secure=False), lockstep=False)


@pytest.mark.parametrize("lockstep", [True, False], ids=["lockstep", "realtime"])
def test_outside_agent_flies_under_secure(tmp_path, lockstep) -> None:
    check_every_action_applied(fly(tmp_path / "sec", lockstep=lockstep, secure=True), lockstep=lockstep)

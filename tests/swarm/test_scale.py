"""The swarm's scale options (issue 19): range-limited beacon cells, beacons every K ticks, several
agents per process (with one shared beacon subscription).  Correctness only; their cost is
measured by bench/bench_swarm.py --sweep.

Network tests use a router on loopback (scouting off); every swarm is one `truav-swarm up`
process that starts and reaps its own children, stopped by the test only if it overruns.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tests.support.waits import wait_matched
from tests.support.runs import up_to_end
from agents.beacon_cells import BeaconCells, CellFollower, feature_range_m, subscription_radius_m
from agents.beacon_schedule import sends_beacon
from agents.state import StateEncoder, neighbour_features
from truav.analysis.trainer import run_chunk
from truav.bus import transport
from truav.config import Config
from truav.wire import keys, schema
from tests.support.swarm_up import learners

RUN = "scale"
SWARM_TIMEOUT_S = 240.0


# -- range-limited beacons: the pure part ---------------------------------------------------------
def test_cells_cover_every_point_within_the_radius_and_nothing_far():
    cells = BeaconCells(cell_m=500.0, area_m=5000.0, radius_m=2200.0)
    rng = np.random.default_rng(7)
    for own in rng.uniform(-50, 5050, size=(200, 2)):
        near = cells.within(*own)
        angle, dist = rng.uniform(0, 2 * np.pi, 50), 2200.0 * np.sqrt(rng.uniform(0, 1, 50))
        for x, y in zip(own[0] + dist * np.cos(angle), own[1] + dist * np.sin(angle)):
            assert cells.cell_of(x, y) in near
        for cell in near:  # every subscribed cell comes within the radius (edge cells extend past the map)
            lo = [-np.inf if c == 0 else c * 500.0 for c in cell]
            hi = [np.inf if c == 9 else (c + 1) * 500.0 for c in cell]
            closest = np.clip(own, lo, hi)
            assert np.hypot(*(closest - own)) <= 2200.0 + 1e-9
    assert len(cells.within(2500.0, 2500.0)) < cells.per_axis ** 2  # it does leave cells out


def test_a_moving_receiver_always_holds_the_cells_within_range_and_seldom_changes_them():
    cells = BeaconCells(cell_m=500.0, area_m=5000.0, radius_m=2360.0)
    follower, rng = CellFollower(cells), np.random.default_rng(3)
    pos, vel, changes = np.array([900.0, 4100.0]), np.array([15.0, -9.0]), 0
    for tick in range(3000):
        if tick % 500 == 0:  # an episode's random redeployment
            pos = rng.uniform(0, 5000, 2)
        pos = np.clip(pos + vel, 0, 5000)
        vel[(pos <= 0) | (pos >= 5000)] *= -1
        held = follower.held
        add, drop = follower.move(*pos)
        assert follower.held == (held | add) - drop and not add & drop
        assert cells.within(*pos) <= follower.held
        changes += bool(add or drop)
    assert changes < 3000 / 20  # about once per cell's width of flight, not every few ticks


def test_range_limited_beacons_give_every_agent_the_state_and_overlap_of_all_beacons():
    """Beacons within the subscription radius give bit-identical state indices and overlap terms."""
    cfg = Config()
    enc = StateEncoder(cfg)
    radius = subscription_radius_m(cfg, beacon_every_ticks=1, max_age_ticks=10)
    assert radius > feature_range_m(cfg) == 2000.0
    cells = BeaconCells(500.0, cfg.scenario.area_m, radius)
    rng = np.random.default_rng(11)
    differ = 0
    for n, swarms in ((2, 20), (5, 20), (20, 20), (100, 5)):
        for _ in range(swarms):
            pos = rng.uniform(0, cfg.scenario.area_m, size=(n, 2))
            for i in range(n):
                others = [j for j in range(n) if j != i]
                near = cells.within(*pos[i])
                heard = [j for j in others if cells.cell_of(*pos[j]) in near
                         and cells.in_range(tuple(pos[i]), tuple(pos[j]))]
                differ += len(heard) != len(others)
                states, overlaps = [], []
                for subset in (others, heard):
                    peers = pos[subset].reshape(1, 1, len(subset), 2)
                    nearest, overlap = neighbour_features(pos[i][None, None], peers,
                                                          np.ones((1, 1, len(subset)), np.bool_),
                                                          cfg.scenario.comm_range_m)
                    states.append(enc.encode(pos[i][None, None], np.array([[3.0]]), np.array([[2.0]]), nearest)[0, 0])
                    overlaps.append(overlap[0, 0])
                assert states[0] == states[1]
                assert overlaps[0] == overlaps[1]  # exactly: far peers add +0.0
    assert differ > 100  # the cells did leave beacons out


def test_a_low_beacon_rate_spreads_senders_over_the_ticks():
    n, every = 20, 10
    for start in (0, 7, 1234):
        window = range(start, start + every)
        for uav in range(n):
            assert sum(sends_beacon(t, uav, every) for t in window) == 1
        assert [sum(sends_beacon(t, u, every) for u in range(n)) for t in window] == [2] * every
    assert all(sends_beacon(t, 3, 1) for t in range(50))


# -- range-limited beacons on the bus -------------------------------------------------------------
def test_a_cell_beacon_reaches_only_subscribers_of_its_cell(bus_factory):
    sender, near, far = bus_factory(keys.uav_identity(1)), bus_factory(keys.uav_identity(2)), bus_factory("world")
    near_box = near.inbox(keys.beacons_in_cell(RUN, (3, 4)))
    far_box = far.inbox(keys.beacons_in_cell(RUN, (5, 4)))
    every = far.inbox(keys.all_beacons_in_cells(RUN))
    assert transport.expected_kind(keys.uav_beacon_in_cell(RUN, 1, (3, 4))) == schema.KIND_BEACON
    assert wait_matched(sender, keys.uav_beacon_in_cell(RUN, 1, (3, 4)))  # subscriptions reach the router
    sender.publish(keys.uav_beacon_in_cell(RUN, 1, (3, 4)), schema.Beacon(uav=1, tick=5, pos=(1700.0, 2100.0),
                                                                          vel=(0.0, 0.0)))
    deadline = time.monotonic() + 5
    got, seen = [], []
    while time.monotonic() < deadline and not (got and seen):
        got += near_box.drain()
        seen += every.drain()
        time.sleep(0.02)
    assert [r.msg.tick for r in got] == [5] and [r.msg.uav for r in seen] == [1]
    assert far_box.drain() == []
    with pytest.raises(PermissionError):  # a UAV still publishes only under its own prefix
        sender.publish(keys.uav_beacon_in_cell(RUN, 2, (3, 4)), schema.Beacon(uav=2, tick=5, pos=(0.0, 0.0),
                                                                              vel=(0.0, 0.0)))
    with pytest.raises(ValueError):
        keys.uav_beacon_in_cell(RUN, 1, (-1, 0))


# -- command line: one line, exit 2 ---------------------------------------------------------------
@pytest.mark.parametrize("argv, fragment", [
    (["up", "--lockstep", "--beacon-hz", "1"], "--beacon-hz: lock-step waits"),
    (["up", "--lockstep", "--beacon-cell", "500"], "--beacon-cell: lock-step waits"),
    (["up", "--beacon-hz", "3"], "--beacon-hz 3: must divide --rate 10"),
    (["up", "--agents-per-process", "2", "--fault-plan", "deploy/plans/crash-and-freeze.toml"],
     "--agents-per-process 2: the fault plan"),
    (["agent", "--id", "0", "--id", "1", "--checkpoint", "x.npz"], "--checkpoint x.npz: with several --id, put {id}"),
    (["agent", "--id", "1", "--id", "1"], "--id: UAV id(s) [1] given twice"),
    (["up", "--share-beacons"], "--share-beacons: shares one beacon subscription"),
    (["up", "--beacon-cell", "500", "--set", "learner.neighbour_sectors=8"], "--beacon-cell 500: learner.neighbour_sectors"),
    (["agent", "--id", "0", "--lockstep", "--beacon-every", "10"], "--beacon-every: lock-step waits"),
])
def test_scale_option_mistakes_are_one_line_usage_errors(argv, fragment, tmp_path):
    proc = subprocess.run([sys.executable, "-m", "truav.cli.swarm", *argv, *(learners() if argv[0] == "up" else []), "--out" if argv[0] == "up" else "--run",
                           str(tmp_path / "out") if argv[0] == "up" else "x"], capture_output=True, text=True,
                          timeout=60, cwd=Path(__file__).parents[2])
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and fragment in lines[0], proc.stderr
    assert not (tmp_path / "out").exists()


# -- whole swarms -------------------------------------------------------------------------------
def _up(tmp: Path, name: str, cfg: Config, *args: str) -> Path:
    return up_to_end(tmp, name, cfg, *args, timeout_s=SWARM_TIMEOUT_S)


def test_agents_sharing_processes_keep_their_identities_and_learn_what_the_trainer_learns(tmp_path):
    """Lock-step, --secure (one certificate per agent, the router's access control), 5 agents in
    processes of 2, 2 and 1 with a shared beacon subscription: every Q-table equals the trainer's."""
    seed, episodes = 4, 6
    cfg = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": 10, "n_uavs": 5},
                           roads={"warmup_steps": 10}, learner={"episodes": episodes})
    expected = run_chunk("truav", cfg, [seed], episodes).q[0]
    out = _up(tmp_path, "shared", cfg, "--lockstep", "--secure", "--seed", str(seed), "--episodes", str(episodes),
              "--agents-per-process", "2", "--share-beacons")
    assert sorted(p.name for p in (out / "logs").glob("agent*.log")) == ["agent4.log", "agents0-1.log",
                                                                         "agents2-3.log"]
    for i in range(5):
        with np.load(out / f"agent{i}.npz") as ck:
            assert int(ck["steps"]) == episodes * 10
            np.testing.assert_array_equal(ck["q"], expected[i])
        stats = json.loads((out / f"agent{i}.json").read_text())
        assert stats["bus"]["rejected"] == {}
        heard = {tuple(x) for x in stats["beacon_latency_from"]}
        assert {s for s, _ in heard} == set(range(5)) - {i}  # every peer's beacons, through the shared subscription
    log = (out / "logs" / "agents0-1.log").read_text()
    assert "uav 0 joined" in log and "uav 1 joined" in log


def test_real_time_swarm_with_cells_and_a_low_beacon_rate(tmp_path):
    """Real time, range-limited beacons at 2 Hz (every 5th tick), 2 agents per process: the run is ok,
    every beacon heard was sent in its sender's beacon ticks, and the cells left some out."""
    n = 6
    cfg = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": 40, "n_uavs": n,
                                     "comm_range_m": 150.0}, roads={"warmup_steps": 10},
                           learner={"neighbour_edges_m": (300.0, 600.0)})
    out = _up(tmp_path, "cells", cfg, "--episodes", "1", "--beacon-hz", "2", "--beacon-cell", "250",
              "--agents-per-process", "2", "--seed", "2",
              "--max-missed", "1")  # a busy host's missed actions are not what this test is about
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outcome"]["result"] == "ok"
    assert summary["control_plane"]["beacons"] > 0  # the supervisor hears cell beacons
    heard = 0
    for i in range(n):
        stats = json.loads((out / f"agent{i}.json").read_text())
        pairs = stats["beacon_latency_from"]
        assert all(sends_beacon(tick, sender, 5) for sender, tick in pairs)
        heard += len(pairs)
    sent = summary["control_plane"]["beacons"]
    assert heard < sent * (n - 1)

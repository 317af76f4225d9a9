"""SUMO traffic (scenario.mobility = "sumo"): a tiny SUMO scenario is built
once (libsumo), its trace's positions are SUMO's own (an independent run of
the `sumo` binary over TraCI drives the same vehicles to the same places at
every step), lie on the network's lanes, and are what the world replays; the
fused trainer equals the step-by-step driver on it; `truav train --mobility
sumo` runs; without SUMO, asking for it is one line and exit 2."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from truav import seeding
from truav.analysis import sumo_traffic
from truav.config import Config, to_toml
from truav.errors import UserError
from world import sumo_scenario
from world.env import World
from world.uavs import HOVER

TINY = {"scenario": {"mobility": "sumo", "area_m": 1000.0, "n_vehicles": 12, "n_uavs": 2, "steps_per_episode": 10,
                     "rsu_intersections": [[1, 1], [3, 3]]},
        "roads": {"major_intersections": [[1, 1], [3, 3]], "warmup_steps": 5,
                  "hotspot_move_prob": 0.5, "hotspot_step_blocks": 1},  # hotspots that move (--preset paper)
        "learner": {"episodes": 4},
        "sumo": {"trace_episodes": 3, "warmup_s": 20.0}}


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """(config, cache root, trace path) of the tiny scenario, built once; the cache in TRUAV_TRACE_CACHE."""
    root = tmp_path_factory.mktemp("traces")
    cfg = Config().replace(**TINY)
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("TRUAV_TRACE_CACHE", str(root))
        path, built = sumo_traffic.build_trace(cfg)
        assert built
        assert sumo_traffic.build_trace(cfg) == (path, False)  # cached by scenario and seed
        yield cfg, root, path


@pytest.mark.filterwarnings("ignore:Module 'rtree' not available")
def test_trace_is_sumos_own_positions_on_its_lanes(tiny):
    import sumolib
    import traci
    cfg, _, path = tiny
    trace = sumo_traffic.read_trace(path)
    assert trace.positions.shape == (3 * 10 + 1, 12, 2) and trace.active.all()
    net_file = path.parent / sumo_traffic.NET_FILE
    trips, edges = sumo_traffic.drive_inputs(cfg, path.parent)
    # The same scenario through the sumo binary and TraCI (not libsumo): the same position at every step.
    seen = []
    traci.start([os.path.join(sumo_traffic.sumo_home(), "bin", "sumo"),
                 *sumo_scenario.sumo_args(cfg, str(net_file))])
    try:
        def on_row(row, pos, active):
            for k in range(pos.shape[0]):
                assert tuple(pos[k]) == traci.vehicle.getPosition(f"v{k}")
            seen.append(pos.copy())
        sumo_scenario.drive(traci, cfg, trips, edges, on_row)
    finally:
        traci.close()
    np.testing.assert_array_equal(np.stack(seen), trace.positions)
    assert np.ptp(trace.positions, axis=0).max() > 100.0  # the vehicles drive
    # Every position on a lane of the network (junctions' internal lanes included), within a centimetre.
    net = sumolib.net.readNet(str(net_file), withInternal=True)
    assert not net.getNeighboringLanes(125.0, 125.0, 0.01)  # a block's middle is on none
    for x, y in trace.positions.reshape(-1, 2)[::7]:
        near = net.getNeighboringLanes(x, y, 0.01, includeJunctions=True)
        assert near, f"({x:.2f}, {y:.2f}) is on no lane"


def test_world_replays_the_trace(tiny):
    cfg, _, path = tiny
    trace = sumo_traffic.read_trace(path)
    world = World(cfg, 2, trace)
    world.reset([seeding.world_rng(s) for s in (3, 4)])
    hover = np.full((2, cfg.scenario.n_uavs), HOVER, np.int64)
    for episode in range(4):
        if episode:
            world.start_episode()
        rows = [trace.episode_row0(int(o), episode) for o in world._trace_offset]
        np.testing.assert_array_equal(world.vehicle_xy(), trace.positions[rows])
        done, t = False, 0
        while not done:
            _, _, done = world.step(hover)
            t += 1
            np.testing.assert_array_equal(world.vehicle_xy(), trace.positions[[r + t for r in rows]])
    # Consecutive episodes take consecutive windows, wrapping around the trace.
    assert all(r == trace.episode_row0(int(o), 3) for r, o in zip(rows, world._trace_offset))
    assert trace.episode_row0(2, 1) == 0 and trace.episode_row0(0, 1) == 10


def test_fused_trainer_equals_the_step_path_on_sumo_traffic(tiny, monkeypatch):
    from agents.controller import TruavController
    from truav.analysis.driver import run_episodes
    cfg, root, _ = tiny
    monkeypatch.setenv("TRUAV_TRACE_CACHE", str(root))
    out = []
    for fused in (False, True):
        ctrl = TruavController(cfg, [0, 7], train=True)
        ctrl.fused = fused
        out.append((run_episodes(cfg, [0, 7], ctrl, 4), ctrl.learners.q))
    (ref, q_ref), (got, q_got) = out
    for k in ref:
        np.testing.assert_array_equal(got[k], ref[k], err_msg=k)
    np.testing.assert_array_equal(q_got, q_ref)
    assert np.nansum(ref["generated"]) > 0


def _cli(args, env, cwd):
    return subprocess.run([sys.executable, "-m", "truav.cli", *args], capture_output=True, text=True, env=env,
                          cwd=cwd, timeout=600)


def test_train_mobility_sumo_runs(tiny, tmp_path):
    cfg, root, _ = tiny
    plain = {k: v for k, v in TINY.items()}
    plain["scenario"] = {k: v for k, v in TINY["scenario"].items() if k != "mobility"}
    (tmp_path / "tiny.toml").write_text(to_toml(Config().replace(**plain)))
    env = {**os.environ, "TRUAV_TRACE_CACHE": str(root)}
    done = _cli(["train", "--mobility", "sumo", "--config", "tiny.toml", "--seeds", "2", "--workers", "2",
                 "--episodes", "3", "--quiet", "--out", "runs/t"], env, tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "on SUMO traffic" in done.stdout
    run = tmp_path / "runs" / "t"
    assert 'mobility = "sumo"' in (run / "config.toml").read_text()
    assert np.load(run / "qtables.npz")["q"].shape[:2] == (2, 2)


def test_without_sumo_asking_for_it_is_one_line(tmp_path):
    """A machine without the extra: `sumo` cannot be imported (a None in sys.modules)."""
    code = ("import sys; sys.modules['sumo'] = None; sys.modules['libsumo'] = None; from truav.cli.main import main; "
            "sys.exit(main(sys.argv[1:]))")
    for args in (["train", "--mobility", "sumo", "--out", "runs/x"], ["traffic", "build"]):
        done = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, cwd=tmp_path,
                              timeout=120)
        assert done.returncode == 2, done.stderr
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1 and "pip install -e '.[sumo]'" in lines[0], done.stderr
        assert not (tmp_path / "runs").exists()


def test_lockstep_swarm_on_sumo_traffic_learns_the_trainers_tables(tiny, tmp_path, monkeypatch):
    """`truav-swarm up --lockstep --mobility sumo`: the world process replays the same trace, and every agent's
    Q-table equals the in-process trainer's, entry for entry, as does each episode's coverage."""
    import json

    from tests.support.runs import run_to_end
    from truav.analysis.trainer import run_chunk
    cfg, root, _ = tiny
    monkeypatch.setenv("TRUAV_TRACE_CACHE", str(root))
    seed, episodes = 3, cfg.learner.episodes
    expected = run_chunk("truav", cfg, [seed], episodes)
    plain = Config().replace(**{**TINY, "scenario": {k: v for k, v in TINY["scenario"].items() if k != "mobility"}})
    (tmp_path / "tiny.toml").write_text(to_toml(plain))
    out = tmp_path / "swarm"
    cmd = [sys.executable, "-m", "truav.cli.swarm", "up", "--scheme", "truav", "--lockstep", "--mobility", "sumo", "--seed", str(seed),
           "--run", "sumo", "--episodes", str(episodes), "--scenario", str(tmp_path / "tiny.toml"), "--out", str(out),
           "--quiet", "--no-plot"]
    rc = run_to_end(cmd, tmp_path / "swarm.log", 180.0, term_wait_s=30)
    assert rc == 0, (tmp_path / "swarm.log").read_text(errors="replace")
    for i in range(cfg.scenario.n_uavs):
        with np.load(out / f"agent{i}.npz") as ck:
            assert np.array_equal(ck["q"], expected.q[0, i]), f"agent {i}"
    world = json.loads((out / "world.json").read_text())
    assert [e["coverage_pct"] for e in world["episodes"]] == list(expected.metrics["coverage_pct"][:, 0])


def test_velocity_experiment_runs_on_sumo_traffic(tiny, tmp_path):
    _, root, _ = tiny
    plain = Config().replace(**{**TINY, "scenario": {k: v for k, v in TINY["scenario"].items() if k != "mobility"}})
    (tmp_path / "tiny.toml").write_text(to_toml(plain))
    env = {**os.environ, "TRUAV_TRACE_CACHE": str(root)}
    done = _cli(["experiment", "velocity", "--mobility", "sumo", "--config", "tiny.toml", "--schemes", "truav",
                 "--seeds", "1", "--episodes", "2", "--eval-episodes", "1", "--speeds", "10", "--workers", "1",
                 "--quiet", "--out", "runs/v"], env, tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    assert 'mobility = "sumo"' in (tmp_path / "runs" / "v" / "config.toml").read_text()
    assert (tmp_path / "runs" / "v" / "velocity.csv").is_file()


def test_a_trace_is_keyed_by_what_shapes_it_and_refused_where_it_does_not_fit(tiny):
    cfg, _, path = tiny
    key = sumo_scenario.cache_key(cfg, "1.28.0")
    # UAV speed, learner and packets leave the traffic alone: one trace serves the velocity sweep.
    assert sumo_scenario.cache_key(cfg.replace(scenario={"uav_speed_mps": 25.0}, learner={"episodes": 9},
                                               traffic={"packet_rate_hz": 1.0}), "1.28.0") == key
    for other in ({"scenario": {"n_vehicles": 13}}, {"sumo": {"trace_seed": 1}}, {"roads": {"block_m": 200.0}},
                  {"roads": {"hotspot_move_prob": 0.0}}):
        assert sumo_scenario.cache_key(cfg.replace(**other), "1.28.0") != key, other
    assert sumo_scenario.cache_key(cfg, "1.29.0") != key
    trace = sumo_traffic.read_trace(path)
    for other, why in (({"n_vehicles": 13}, "13"), ({"steps_per_episode": 20}, "have 20 steps")):
        assert why in trace.mismatch(cfg.replace(scenario=other))
        with pytest.raises(ValueError, match="does not fit"):
            World(cfg.replace(scenario=other), 1, trace)
    with pytest.raises(ValueError, match="needs a trace"):
        World(cfg, 1)
    # Traffic lights at the major intersections; the grid's junctions where the world has them.
    args = sumo_scenario.netgenerate_args(cfg, "x.net.xml")
    assert args[args.index("--tls.set") + 1] == "1/1,3/3"
    assert args[args.index("--grid.number") + 1] == "5" and args[args.index("--grid.length") + 1] == "250.0"


def _damaged(path, how: str) -> None:
    good = path.read_bytes()
    path.write_bytes({"empty": b"", "truncated": good[: len(good) // 2],
                      "corrupt": good[: len(good) // 3] + b"X" * 32 + good[len(good) // 3 + 32:]}[how])


@pytest.mark.parametrize("how", ["empty", "truncated", "corrupt"])
def test_a_damaged_cached_trace_is_one_line_before_anything_starts(tiny, tmp_path, how):
    """A cached trace.npz cut short or flipped (a full disk, a crash mid-copy): train, up and traffic build
    name it in one line, exit 2, before --out is made or a process started (not a BadZipFile traceback
    from the world or a worker)."""
    import shutil
    cfg, root, path = tiny
    cache = tmp_path / "cache"
    shutil.copytree(root, cache)
    _damaged(cache / path.relative_to(root), how)
    plain = Config().replace(**{**TINY, "scenario": {k: v for k, v in TINY["scenario"].items() if k != "mobility"}})
    (tmp_path / "tiny.toml").write_text(to_toml(plain))
    env = {**os.environ, "TRUAV_TRACE_CACHE": str(cache)}
    for cmd in (["truav.cli", "train", "--mobility", "sumo", "--config", "tiny.toml", "--seeds", "1", "--episodes",
                 "1", "--out", "runs/t"],
                ["truav.cli.swarm", "up", "--mobility", "sumo", "--scenario", "tiny.toml", "--episodes", "1",
                 "--out", "runs/u"],
                ["truav.cli", "traffic", "build", "--config", "tiny.toml", "--set", "scenario.mobility=sumo"]):
        done = subprocess.run([sys.executable, "-m", *cmd], capture_output=True, text=True, env=env, cwd=tmp_path,
                              timeout=120)
        lines = done.stderr.strip().splitlines()
        assert done.returncode == 2 and len(lines) == 1, (cmd, done.stderr[-2000:])
        assert "trace.npz: not a readable trace" in lines[0] and "--force" in lines[0], lines
        assert not (tmp_path / "runs").exists(), cmd


def test_a_cache_that_cannot_hold_traces_or_a_trace_too_large_is_one_line(tiny, tmp_path):
    cfg, _, _ = tiny
    (tmp_path / "file").write_text("x")
    with pytest.raises(UserError, match="SUMO trace cache .*cannot create the directory"):
        sumo_traffic.build_trace(cfg, tmp_path / "file")
    (tmp_path / "cache" / sumo_traffic.trace_dir(cfg, tmp_path / "cache").name / "trace.npz").mkdir(parents=True)
    with pytest.raises(UserError, match="not a regular file"):
        sumo_traffic.build_trace(cfg, tmp_path / "cache")
    huge = cfg.replace(scenario={"steps_per_episode": 1_000_000}, sumo={"trace_episodes": 100_000})
    with pytest.raises(UserError, match="more than half this machine's memory"):
        sumo_traffic.build_trace(huge, tmp_path / "cache")  # at once, not after hours of randomTrips.py
    done = _cli(["traffic", "build", "--cache", "file"], os.environ, tmp_path)
    assert done.returncode == 2 and done.stderr.strip() == "truav: error: --cache file: exists and is not a directory"

"""`truav-swarm steer`: one UAV of a running lock-step swarm taken over from outside flies toward the point
given, then is released; world.json, summary.json and the closing summary name the override, the recording
holds it, and `truav log resim` reproduces the run with it bit for bit. Mistakes are one line, exit 2."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import time

from recorder.reader import iter_messages
from tests.support.swarm_up import up  # noqa: F401
from truav.bus.transport import Bus, make_config
from truav.cli.main import main as truav_main
from truav.wire import keys, schema

GOAL = (2500.0, 2500.0)
UAV = 1
STEER = [sys.executable, "-m", "truav.cli.swarm", "steer"]


def steer(out, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([*STEER, "--out", str(out), *args], capture_output=True, text=True, timeout=120)


def test_a_steered_uav_flies_to_the_point_and_the_run_re_simulates_exactly(up, tmp_path, capsys) -> None:
    rec = tmp_path / "steer.mcap"
    u = up("steer", "--agents", "3", "--lockstep", "--episodes", "1", "--steps", "100000", "--record", str(rec))
    endpoint = u.wait_ticking()
    bad = [steer(u.out, "7", "--to", "1,1"), steer(u.out, str(UAV), "--to", "99999,1"),
           steer(u.out, str(UAV), "--to", "1,1", "--release")]
    for r in bad:
        assert r.returncode == 2 and r.stderr.count("\n") == 1 and "Traceback" not in r.stderr, r.stderr
    track: dict[int, tuple[float, float]] = {}
    with Bus("observer", u.run, make_config(connect=[endpoint], connect_timeout_ms=5000)) as bus:
        bus.subscribe(keys.world_positions(u.run), lambda k, m, r, t: track.__setitem__(m.tick, m.uavs[UAV]))
        done = steer(u.out, str(UAV), "--to", f"{GOAL[0]:g},{GOAL[1]:g}")
        assert done.returncode == 0, done.stderr
        start = int(done.stdout.rsplit("from tick ", 1)[1])
        deadline = time.monotonic() + 60
        while max(track, default=-1) < start + 30 and time.monotonic() < deadline:
            time.sleep(0.05)
        released = steer(u.out, str(UAV), "--release")
        assert released.returncode == 0 and "released" in released.stdout, released.stderr
    down = subprocess.run([sys.executable, "-m", "truav.cli.swarm", "down", "--out", str(u.out)],
                          capture_output=True, text=True, timeout=120)
    assert down.returncode == 0, down.stderr
    assert u.wait(timeout=120) == 130, u.output()  # stopped by `down`: "interrupted"
    # It flew toward the point: each step 15 m nearer (full speed, 1 s steps; a diagonal heading: a little less).
    dist = [math.dist(track[t], GOAL) for t in range(start, start + 30) if t in track]
    assert len(dist) >= 20 and all(b < a - 5.0 or b <= 15.0 for a, b in zip(dist, dist[1:])), dist
    summary = json.loads((u.out / "summary.json").read_text())
    world = json.loads((u.out / "world.json").read_text())
    phases = [(o["uav"], o["phase"], o["by"]) for o in summary["overrides"]]
    assert phases == [(UAV, "start", "operator"), (UAV, "end", "operator")] and world["overrides"] == summary["overrides"]
    assert summary["overrides"][0]["tick"] == start and (summary["overrides"][0]["x"], summary["overrides"][0]["y"]) == GOAL
    assert f"override: UAV {UAV} steered by operator from tick {start}" in u.output()
    events = [schema.decode(p) for _, p, _, _ in iter_messages(rec, include=[keys.fault(u.run, "override")])]
    assert [(e.phase, e.target, e.params["tick"]) for e in events][:1] == [("start", f"uav/{UAV}", start)]
    assert len(events) == 2
    code = truav_main(["log", "resim", str(rec), "--quiet"])
    out = capsys.readouterr().out
    assert code == 0 and "result: reproduced" in out and "overrides: 2 start(s) and end(s)" in out, out

"""The recorder benchmarks' messages: beacons and the 20-agent swarm mix, built with
msgpack directly, with the same fields and sizes as ``truav.wire.schema`` (so the
benches do not depend on it). Used by bench_recorder.py and bench_recorder_bus.py.
"""

from __future__ import annotations

import msgpack

TARGET_MSGS_S = 100_000
N_UAVS = 20
TICK_HZ = 10
WORLD_MSGS_PER_TICK = 3  # tick, positions, step metrics (episode metrics are rare)
SWARM_MSGS_PER_TICK = N_UAVS * 3 + WORLD_MSGS_PER_TICK  # beacon + obs + action per agent
RUN = "bench"
T0 = 1_732_200_000_000_000_000

Batch = list[tuple[str, bytes, int]]


def _env(kind: str, src: str, seq: int, t: int) -> dict:
    return {"v": 1, "kind": kind, "src": src, "seq": seq, "t": t}


def beacons(n: int) -> Batch:
    out = []
    for i in range(n):
        uav, tick = i % N_UAVS, i // N_UAVS
        t = T0 + tick * 100_000_000 + uav * 1000
        body = {**_env("beacon", f"uav/{uav}", tick, t), "uav": uav, "tick": tick,
                "pos": [1234.5678 + tick, 987.654321 - uav], "vel": [12.25, -3.5]}
        out.append((f"truav/{RUN}/uav/{uav}/beacon", msgpack.packb(body), t + 400_000))
    return out


def swarm_mix(n_ticks: int) -> Batch:
    out = []
    for tick in range(n_ticks):
        t = T0 + tick * 100_000_000
        w = f"truav/{RUN}/world"
        out.append((f"{w}/tick", msgpack.packb({**_env("tick", "world", tick, t), "tick": tick, "episode": 0,
                                                 "sim_time": tick * 0.1, "deadline_ms": 80.0, "n_uavs": N_UAVS}), t))
        for uav in range(N_UAVS):
            u = f"truav/{RUN}/uav/{uav}"
            seq = tick * N_UAVS + uav
            out.append((f"{u}/obs", msgpack.packb({
                **_env("obs", "world", seq, t), "tick": tick, "episode": 0, "uav": uav,
                "pos": [100.0 + uav, 200.0 + tick], "vehicles_in_range": 7, "queued_packets": 3, "relayed": 41,
                "covered": 9, "energy_j": 1234.5, "speed_max": 20.0, "done": False}), t + 1000))
        for uav in range(N_UAVS):
            u = f"truav/{RUN}/uav/{uav}"
            out.append((f"{u}/beacon", msgpack.packb({
                **_env("beacon", f"uav/{uav}", tick, t), "uav": uav, "tick": tick,
                "pos": [100.0 + uav, 200.0 + tick], "vel": [12.25, -3.5]}), t + 2000))
            out.append((f"{u}/action", msgpack.packb({
                **_env("action", f"uav/{uav}", tick, t), "uav": uav, "tick": tick, "action": tick % 16}), t + 3000))
        out.append((f"{w}/positions", msgpack.packb({
            **_env("positions", "world", tick, t), "tick": tick,
            "uavs": [[100.0 + u, 200.0 + tick] for u in range(N_UAVS)],
            "vehicles": [[10.0 * v, 5.0 * v] for v in range(50)]}), t + 4000))
        out.append((f"truav/{RUN}/metrics/step", msgpack.packb({
            **_env("metrics", "world", tick, t), "scope": "step", "tick": tick, "episode": 0,
            "values": {"reward": 0.5, "coverage": 0.8, "delivered": 12.0, "dropped": 1.0, "energy": 99.0}}), t + 5000))
    return out

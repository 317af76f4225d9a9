"""A synthesised swarm recording (McapLog, no network), for the report and `truav log` tests."""

from __future__ import annotations

import math
from pathlib import Path

import msgpack

from recorder.mcap_log import McapLog
from recorder.metadata import CONFIG_METADATA, config_metadata
from truav.config import Config, to_toml

RUN = "rep"
T0 = 1_700_000_000_000_000_000
MS = 1_000_000
N_UAVS = 4
TICKS = 120  # 12 s at 10 Hz, two episodes of 60 ticks


class Seq:
    """Per-(src, kind) sequence numbers."""

    def __init__(self) -> None:
        self.next: dict[tuple[str, str], int] = {}

    def __call__(self, src: str, kind: str) -> int:
        n = self.next.get((src, kind), 0)
        self.next[(src, kind)] = n + 1
        return n


def msg(seq: Seq, kind: str, src: str, t: int, **body: object) -> bytes:
    return msgpack.packb({"v": 1, "kind": kind, "src": src, "seq": seq(src, kind), "t": t, **body})


def make_swarm_recording(path: Path, *, config: bool = True, beacons: bool = True, crash_uav: int = 2,
                         finish: bool = True, heard_loss: float | None = None) -> dict[str, int]:
    """A 4-UAV run: UAVs circle, vehicles on two roads, a loss fault (start/end) and a crash
    (start only) during which UAV ``crash_uav`` stops beaconing.  Returns counts.

    With ``heard_loss``, each agent also sends a health report every 10 ticks with the beacons it heard
    per sender, each of its peers' beacons lost at the receiver with that probability (seeded draws)."""
    import random

    seq = Seq()
    counts = {"metrics": 0, "beacons": 0}
    draw = random.Random(45)
    heard = [[0] * N_UAVS for _ in range(N_UAVS)]  # [receiver][sender]
    log = McapLog(path)
    if config:
        log.set_metadata(CONFIG_METADATA, config_metadata(to_toml(Config())))
    for tick in range(TICKS):
        t = T0 + tick * 100 * MS
        episode, et = divmod(tick, 60)
        log.write(f"truav/{RUN}/world/tick", msg(seq, "tick", "world", t, tick=et, episode=episode,
                                                 sim_time=float(et), deadline_ms=80.0, n_uavs=N_UAVS), t + MS)
        pos = []
        for u in range(N_UAVS):
            angle = 2 * math.pi * (et / 60 + u / N_UAVS)
            xy = [2500 + (800 + 300 * u) * math.cos(angle), 2500 + (800 + 300 * u) * math.sin(angle)]
            pos.append(xy)
            log.write(f"truav/{RUN}/uav/{u}/obs", msg(seq, "obs", "world", t, tick=et, episode=episode, uav=u, pos=xy,
                                                      vehicles_in_range=3, queued_packets=1, relayed=1, covered=3,
                                                      energy_j=10.0, speed_max=15.0, done=False), t + 2 * MS)
            crashed = crash_uav == u and tick >= 90
            if beacons and not crashed:
                counts["beacons"] += 1
                sent = t + 5 * MS
                log.write(f"truav/{RUN}/uav/{u}/beacon", msg(seq, "beacon", f"uav/{u}", sent, uav=u, tick=et,
                                                             pos=xy, vel=[1.0, 0.0]), sent + (1 + u) * MS)
                for r in range(N_UAVS):
                    if heard_loss is not None and r != u and draw.random() >= heard_loss:
                        heard[r][u] += 1
        if heard_loss is not None and tick % 10 == 0:
            for r in range(N_UAVS):
                if crash_uav == r and tick >= 90:
                    continue
                sent = t + 50 * MS
                log.write(f"truav/{RUN}/uav/{r}/health", msg(seq, "health", f"uav/{r}", sent, inc=7, uav=r,
                                                             last_tick=et, steps=tick, stale_obs_skipped=0,
                                                             rejected={}, senders={}, heard=list(heard[r])),
                          sent + MS)
        if tick % 10 == 0:
            vehicles = [[250.0 * (k % 21), 1000.0] for k in range(21)] + [[2500.0, 100.0 * k] for k in range(50)]
            log.write(f"truav/{RUN}/world/positions", msg(seq, "positions", "world", t, tick=et, uavs=pos,
                                                          vehicles=vehicles), t + 3 * MS)
        values = {"coverage_pct": 40.0 + 10 * math.sin(tick / 10), "delivered": float(tick % 7), "pdr": 0.5}
        log.write(f"truav/{RUN}/metrics/step", msg(seq, "metrics", "world", t, scope="step", tick=et,
                                                   episode=episode, values=values), t + 4 * MS)
        counts["metrics"] += 1
        if et == 59:
            log.write(f"truav/{RUN}/metrics/episode", msg(seq, "metrics", "world", t, scope="episode", tick=et,
                                                          episode=episode, values={"pdr": 0.5, "reward": 1.0}),
                      t + 4 * MS)
            counts["metrics"] += 1
        if tick in (30, 50):
            phase = "start" if tick == 30 else "end"
            log.write(f"truav/{RUN}/fault/loss", msg(seq, "fault", "fault", t, fault="loss", phase=phase,
                                                     target="uav/1", params={"p": 0.5}), t + MS)
        if tick == 90:
            log.write(f"truav/{RUN}/fault/crash", msg(seq, "fault", "fault", t, fault="crash", phase="start",
                                                      target=f"uav/{crash_uav}", params={}), t + MS)
    if finish:
        log.close()
    else:
        log.flush()  # a writer that died after its last flush: no summary, no footer
    return counts


def make_claimed_ids_recording(path: Path, claimed: int = 3000, per_id: int = 3, own_keys: bool = False) -> int:
    """A small recording whose beacons all travel on UAV 0's key but claim ``claimed`` different senders (the
    body's ``uav`` and ``src``), ``per_id`` beacons each: what a hostile or broken writer can put in a file.
    ``own_keys``: each on its claimed UAV's own key instead (consistent, but more UAVs than the schema allows).
    Returns the number of beacons written."""
    seq = Seq()
    n = 0
    with McapLog(path) as log:
        log.set_metadata(CONFIG_METADATA, config_metadata(to_toml(Config())))
        for k in range(per_id):
            for uav in range(claimed):
                t = T0 + (k * claimed + uav) * MS
                log.write(f"truav/{RUN}/uav/{uav if own_keys else 0}/beacon", msg(seq, "beacon", f"uav/{uav}", t, uav=uav, tick=k,
                                                           pos=[float(uav % 5000), float(k)], vel=[1.0, 0.0]), t + MS)
                n += 1
    return n

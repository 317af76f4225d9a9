"""The scale a TRUAV swarm on a cluster reaches, on paper, from measured inputs (docs/explanation/scale.md).

    python docs/scripts/scale_model.py                        # 100, 1,000 and 10,000 UAVs, the page's tables
    python docs/scripts/scale_model.py --uavs 500 --neighbours 20 --cores-per-node 32

Each input is a measurement (its source in --help) or a stated assumption (the beacon rate, the neighbours of
a range-limited beacon, a node's cores). The beacon's size comes from the wire codec itself
(truav.wire.codec.encode of a beacon with full-width fields), the key space from truav.wire.keys. The model:

- every UAV beacons at --rate Hz; all-to-all, each of the n-1 others hears it; range-limited (cells),
  --neighbours of them. Receptions per second: n x rate x hearers, plus the world's observation to each UAV
  and each UAV's action (2 x n x rate).
- CPU: receptions x --us-per-reception (all the swarm's processes' CPU over the UAV-receptions they delivered).
- nodes: CPU over what a node keeps in real time (--cores-per-node x --usable-share); one router per node,
  each linked to the core node's (the plan of truav/swarm/ray_plan.py), agents dealt evenly to the nodes.
- a link: a non-core node's router receives once each beacon a UAV on it hears from another node (UAVs are
  placed by process, not by position, so a node's UAVs hear UAVs of every node) and sends its own UAVs'
  beacons once; the core router sends every other node what it hears: (nodes - 1) links' worth.
- one process (the world; the recorder keeping everything) against --process-msgs-per-s, the rate one
  process was measured to take from the bus.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from truav.wire import codec, keys, schema  # noqa: E402

PER_UAV_KEYS = (keys.uav_obs, keys.uav_beacon, keys.uav_action, keys.uav_health, keys.uav_rejected,
                keys.alive_uav, keys.control_override)
"""The key expressions of UAV i in a default (truav scheme) run: world -> i, i -> all, i -> world, its health,
its refusals, its liveliness token, its steering override. Federated runs add uav/<i>/qshare/<part>, range-limited
beacons uav/<i>/beacon/<cell>, recordings of lock-step runs uav/<i>/snapshot, --scheme central two more."""


def beacon_bytes() -> int:
    """One beacon's encoded size with every field at its widest: the largest UAV id the wire takes, a 63-bit
    tick, sequence and incarnation, a wall-clock time stamp and float positions and velocities."""
    top = keys.MAX_UAVS - 1
    return len(codec.encode(schema.Beacon(src=keys.uav_identity(top), seq=2 ** 40, t=1_800_000_000_000_000_000,
                                          inc=2 ** 63 - 1, uav=top, tick=2 ** 40,
                                          pos=(2452.9176119130184, 1951.0172037876127), vel=(12.5, -3.25))))


@dataclass(frozen=True)
class Row:
    uavs: int
    mode: str
    hearers: int
    receptions_per_s: float
    cores: float
    nodes: int
    link_in_bytes_s: float
    link_out_bytes_s: float
    core_out_bytes_s: float
    process_in_msgs_s: float
    world_msgs_s: float
    recorder_msgs_s: float
    keys: int
    ids_fit: bool


def model(n: int, hearers: int, mode: str, a) -> Row:
    rate, size = a.rate, a.beacon_bytes
    receptions = n * rate * hearers + 2 * n * rate
    cores = receptions * a.us_per_reception * 1e-6
    nodes = max(1, math.ceil(cores / (a.cores_per_node * a.usable_share)))
    on_node = n / nodes
    others = n - on_node
    heard_from_others = others if mode == "all-to-all" else min(others, on_node * hearers * others / max(n - 1, 1))
    link_in = heard_from_others * rate * size if nodes > 1 else 0.0
    link_out = on_node * rate * size if nodes > 1 else 0.0
    # An agent process (--agents-per-process K, one shared beacon subscription) takes in what any of its K UAVs hears.
    k = min(a.per_process, n)
    process_in = rate * (n - 1 if mode == "all-to-all" else min(n - 1, k * hearers))
    return Row(n, mode, hearers, receptions, cores, nodes, link_in, link_out, (nodes - 1) * link_in, process_in,
               2 * n * rate, 3 * n * rate, len(PER_UAV_KEYS) * n, n <= keys.MAX_UAVS)


def bottlenecks(r: Row, a) -> list[str]:
    """The limits the swarm crosses, in the order it meets them (the first is the first bottleneck)."""
    out = []
    if not r.ids_fit:
        out.append(f"UAV ids (at most {keys.MAX_UAVS:,}: truav.wire.keys.MAX_UAVS)")
    if r.world_msgs_s > a.process_msgs_per_s:
        out.append(f"the one world process ({r.world_msgs_s:,.0f} msgs/s)")
    if r.recorder_msgs_s > a.process_msgs_per_s:
        out.append(f"the recorder, recording everything ({r.recorder_msgs_s:,.0f} msgs/s)")
    if r.process_in_msgs_s > a.process_msgs_per_s:
        out.append(f"an agent process's intake ({r.process_in_msgs_s:,.0f} msgs/s)")
    if r.nodes > 1:
        out.append(f"CPU ({r.cores:,.1f} cores: {r.nodes:,} nodes)")
    return out or ["none: one node"]


def mb(x: float) -> str:
    return f"{x / 1e6:,.2f}"


def table(rows: list[Row], a) -> str:
    """The page's table (docs/explanation/scale.md), then the limits each row crosses."""
    out = ["| UAVs | beacons | receptions/s | cores | nodes (= routers) | link in / out MB/s | core router out MB/s | "
           "agent process in msgs/s | world msgs/s | recorder msgs/s | UAV keys |",
           "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        link = f"{mb(r.link_in_bytes_s)} / {mb(r.link_out_bytes_s)}" if r.nodes > 1 else "-"
        core = mb(r.core_out_bytes_s) if r.nodes > 1 else "-"
        out.append(f"| {r.uavs:,} | {r.mode} | {r.receptions_per_s:,.0f} | {r.cores:,.1f} | {r.nodes:,} | {link} | "
                   f"{core} | {r.process_in_msgs_s:,.0f} | {r.world_msgs_s:,.0f} | {r.recorder_msgs_s:,.0f} | "
                   f"{r.keys:,} |")
    out.append("")
    out += [f"- {r.uavs:,} UAVs, {r.mode} ({r.hearers:,} hear each beacon): " + "; then ".join(bottlenecks(r, a))
            for r in rows]
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--uavs", type=int, nargs="+", default=[100, 1000, 10000],
                    help="swarm sizes (default 100 1000 10000)")
    ap.add_argument("--rate", type=float, default=10.0, help="beacons per UAV per second (default 10: up's tick rate, "
                    "one beacon a tick; measured 10.1-10.3/s in the swarm summaries)")
    ap.add_argument("--neighbours", type=int, default=50, help="UAVs that hear a range-limited beacon (an assumption; "
                    "default 50)")
    ap.add_argument("--us-per-reception", type=float, default=12.6, help="CPU microseconds of all the swarm's "
                    "processes per message delivered to a UAV (default 12.6: 100 UAVs, 10 per process, "
                    "--share-beacons, docs/results/benchmarks.md, 'The swarm at scale', 2026-12-02)")
    ap.add_argument("--cores-per-node", type=float, default=2.0, help="a node's cores (default 2: the reference "
                    "machine)")
    ap.add_argument("--usable-share", type=float, default=0.65, help="the share of a node's cores a real-time swarm "
                    "can use and keep its deadlines (default 0.65: about 1.3 of 2 cores, docs/results/benchmarks.md)")
    ap.add_argument("--per-process", type=int, default=10, help="UAVs per agent process (default 10, as measured)")
    ap.add_argument("--process-msgs-per-s", type=float, default=111_000, help="messages per second one process "
                    "takes from the bus (default 111,000: the recorder, bench/bench_recorder_bus.py, 2026-11-22)")
    ap.add_argument("--beacon-bytes", type=int, default=None, help="a beacon's size (default: the wire codec's, "
                    "every field at its widest)")
    a = ap.parse_args(argv)
    if a.beacon_bytes is None:
        a.beacon_bytes = beacon_bytes()
    rows = [model(n, n - 1, "all-to-all", a) for n in a.uavs] + \
        [model(n, min(a.neighbours, n - 1), "range-limited", a) for n in a.uavs]
    print(f"beacon {a.beacon_bytes} B at {a.rate:g} Hz; {len(PER_UAV_KEYS)} key expressions per UAV; "
          f"{a.us_per_reception:g} us CPU per reception; a node keeps {a.cores_per_node * a.usable_share:g} cores "
          f"in real time; one process takes {a.process_msgs_per_s:,.0f} msgs/s")
    print(table(rows, a))
    return 0


if __name__ == "__main__":
    sys.exit(main())

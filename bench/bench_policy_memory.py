"""What a learned policy's agent processes take in memory: a 100-UAV swarm of ``ppo`` against the
Q-learning agents, one UAV per process and several hosted per process.

    python bench/bench_policy_memory.py           # 100 UAVs, lock-step, 100 ticks; ppo, truav; 1 and 10 a process
    python bench/bench_policy_memory.py --quick   # 10 UAVs, 10 ticks: a smoke run
    python bench/bench_policy_memory.py --schemes ppo,spread,truav --per-process 1,5,20

Each run is ``truav-swarm up`` of this checkout under ``--preset paper`` with
``learner.sense_range_m=1500`` (the sensing the shipped ``ppo`` weights were trained with), one episode
of ``--ticks`` ticks, lock-step (``--realtime``: at ``--rate`` Hz). Twice a second its agent processes
(the run's pids.json) are read from /proc (bench/policy_runs.py): RSS and its peak, PSS (shared pages
divided among the processes that map them, so the processes' sum is what they take together) and USS
(what only that process maps). Printed per setting: each process's largest figures (median and maximum
over the processes); the largest total PSS of all agent processes in one sample that read them all (and
the sum of each one's largest, an upper bound), and that total per UAV; the world process's beside them.
Memory does not depend on how busy the machine is, only time does: figures of a loaded machine are still
the policies' memory.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_common  # noqa: E402
import policy_runs  # noqa: E402


def measure(scheme: str, per_process: int, scenario: Path, args) -> dict:
    """One run of ``scheme`` with ``per_process`` UAVs per agent process; its memory figures (MB)."""
    world, sampler, code, why = policy_runs.fly(scheme, scenario, args.agents, args.ticks, per_process=per_process,
                                           lockstep=not args.realtime, rate=args.rate, period_s=0.5)
    agents = {name: peak for name, peak in sampler.peak.items() if name in sampler.uavs}
    mb = {k: np.array([p[k] for p in agents.values()], dtype=float) / 1024 for k in policy_runs.MEMORY_KEYS}
    expected = -(-args.agents // per_process)
    world_peak = sampler.peak.get("world", dict.fromkeys(policy_runs.MEMORY_KEYS, 0))
    return {"scheme": scheme, "per_process": per_process, "agents": args.agents, "ticks": int(world.get("ticks", 0)),
            "exit_code": code, "why": why, "processes_expected": expected, "processes_seen": len(agents),
            "restarted": sum(len(sampler.pids[n]) - 1 for n in agents),
            "uavs_seen": sum(sampler.uavs[n] for n in agents),
            **{f"{k[:-3]}_mb_median": float(np.median(v)) if v.size else float("nan") for k, v in mb.items()},
            **{f"{k[:-3]}_mb_max": float(v.max()) if v.size else float("nan") for k, v in mb.items()},
            "total_pss_mb": sampler.total_pss_kb(expected) / 1024,
            "pss_mb_per_uav": sampler.total_pss_kb(expected) / 1024 / max(args.agents, 1),
            "complete_samples": sum(n == expected for n, _ in sampler.totals),
            "sum_of_peak_pss_mb": float(mb["pss_kb"].sum()),
            "world_rss_mb": world_peak["rss_kb"] / 1024, "world_pss_mb": world_peak["pss_kb"] / 1024,
            "missed_pct": policy_runs.missed_pct(world, args.agents),
            "processes": {n: {k: v / 1024 for k, v in p.items()} for n, p in sorted(agents.items())},
            "mode": "real time" if args.realtime else "lock-step"}


def line(r: dict) -> str:
    seen = "" if r["processes_seen"] == r["processes_expected"] and r["complete_samples"] else \
        (f" (INCOMPLETE: {r['processes_seen']}/{r['processes_expected']} processes sampled, "
         f"{r['complete_samples']} samples of them all)")
    return (f"{r['scheme']:>6s} {r['agents']} UAVs, {r['per_process']} per process ({r['processes_expected']} "
            f"processes, {r['mode']}, {r['ticks']} ticks, exit {r['exit_code']}){seen}: per process RSS "
            f"{r['rss_mb_median']:.1f} MB (max {r['rss_mb_max']:.1f}, peak {r['hwm_mb_max']:.1f}), PSS "
            f"{r['pss_mb_median']:.1f}, USS {r['uss_mb_median']:.1f} MB; all agent processes {r['total_pss_mb']:.0f} "
            f"MB PSS at once (each one's largest, summed: {r['sum_of_peak_pss_mb']:.0f}) = {r['pss_mb_per_uav']:.1f} "
            f"MB per UAV; world RSS {r['world_rss_mb']:.0f} MB"
            + (f"; {r['restarted']} restarts" if r["restarted"] else "")
            + (f"\n       exit {r['exit_code']}: {r['why']}" if r["exit_code"] else ""))


def table(rows: list[dict]) -> str:
    out = ["| scheme | UAVs per process | processes | RSS per process (median, max) MB | PSS per process MB | "
           "USS per process MB | all agent processes, PSS MB (at once; peaks summed) | per UAV, PSS MB |",
           "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        out.append(f"| {r['scheme']} | {r['per_process']} | {r['processes_seen']}/{r['processes_expected']} | "
                   f"{r['rss_mb_median']:.1f}, {r['rss_mb_max']:.1f} | {r['pss_mb_median']:.1f} | "
                   f"{r['uss_mb_median']:.1f} | {r['total_pss_mb']:.0f}; {r['sum_of_peak_pss_mb']:.0f} | "
                   f"{r['pss_mb_per_uav']:.1f} |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = bench_common.parser(__doc__)
    ap.add_argument("--agents", type=int, default=100, help="UAVs in the swarm (default 100)")
    ap.add_argument("--ticks", type=int, default=100, help="ticks of the one episode (default 100)")
    ap.add_argument("--schemes", default="ppo,truav", help="comma-separated: truav (the Q-learning agents) or an "
                    "agent name (default ppo,truav)")
    ap.add_argument("--per-process", default="1,10", metavar="K,K", help="UAVs hosted per agent process, one run "
                    "each (default 1,10)")
    ap.add_argument("--realtime", action="store_true", help="real time at --rate instead of lock-step")
    ap.add_argument("--rate", type=float, default=10.0, help="--realtime: tick rate in Hz (default 10)")
    ap.add_argument("--quick", action="store_true", help="a smoke run: 10 UAVs, 10 ticks, 1 and 5 per process")
    policy_runs.add_speed_option(ap)
    ap.add_argument("--json", type=Path, metavar="FILE", help="also write the rows as JSON (each "
                    "process's figures under 'processes')")
    args = ap.parse_args(argv)
    if args.speed is not None and not 0.1 <= args.speed <= 100:
        print(f"bench_policy_memory: error: --speed: a UAV speed in [0.1, 100] m/s, got {args.speed:g}", file=sys.stderr)
        return 2
    if args.quick:
        args.agents, args.ticks = 10, 10
        if args.per_process == ap.get_default("per_process"):
            args.per_process = "1,5"
    try:
        ks = [int(k) for k in args.per_process.split(",") if k]
    except ValueError:
        ks = []
    schemes = [s for s in args.schemes.split(",") if s]
    if not ks or min(ks) < 1:
        print(f"bench_policy_memory: error: --per-process: positive integers, got {args.per_process!r}",
              file=sys.stderr)
        return 2
    if not schemes or args.agents < 1 or args.ticks < 1 or args.rate <= 0:
        print("bench_policy_memory: error: --schemes must name one, --agents, --ticks and --rate be positive",
              file=sys.stderr)
        return 2
    rows = []
    with tempfile.TemporaryDirectory(prefix="truav-bench-memory-") as tmp:
        scenario = policy_runs.write_scenario(Path(tmp) / "paper-sense1500.toml", args.speed)
        for k in ks:
            for scheme in schemes:
                try:
                    r = measure(scheme, k, scenario, args)
                except RuntimeError as exc:
                    print(f"bench_policy_memory: {exc}", file=sys.stderr)
                    return 1
                rows.append(r)
                print(line(r), flush=True)
    print(table(rows))
    bench_common.write_rows(args.json, rows)
    bad = [r for r in rows if r["exit_code"] != 0 or r["processes_seen"] != r["processes_expected"]
           or not r["complete_samples"]]
    if bad:
        print(f"bench_policy_memory: {len(bad)} run(s) did not end ok or were not sampled whole (see above)",
              file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())

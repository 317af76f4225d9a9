"""Whether a learned policy keeps up in real time: 20 UAVs of ``ppo`` against TRUAV's Q-learning agents,
runs alternated, missed actions and the agents' CPU per scheme.

    python bench/bench_policy_realtime.py                 # 20 UAVs, 10 Hz, 60 s a run, 3 rounds of truav, ppo
    python bench/bench_policy_realtime.py --repeat 5      # more rounds: the run-to-run spread
    python bench/bench_policy_realtime.py --quick --anyway    # a smoke run (4 UAVs, 5 s, 1 round) on a busy machine
    python bench/bench_policy_realtime.py --schemes truav,ppo-disc --speed 5   # ppo-disc flies its own network below 10 m/s

Each run is ``truav-swarm up`` of this checkout under ``--preset paper`` with ``learner.sense_range_m=1500``
(the sensing the shipped ``ppo`` weights were trained with): one episode of ``--seconds x --rate`` ticks at
``--rate`` Hz, every UAV an agent process, flying ``truav`` (the Q-learning agents, ``--scheme truav``,
learning as they do there) or an agent class by name (``ppo``; ``--schemes`` takes any, e.g. ``spread``). The figures
come from the run's world.json (the share of actions missed: UAVs x ticks with no action in time,
per_uav's ``missed``; tick lateness p99) and from /proc (bench/policy_runs.py: the agent processes' CPU
over the world's first to last tick, in cores and per UAV). The end prints, per scheme, the median of each
figure and its missed share against ``truav``'s.

A figure measured beside other jobs is noise, not the policy's cost: the benchmark refuses to start
(exit 2) while the 1-minute load average is at or above ``--max-load`` (default 1); ``--anyway`` runs
regardless and marks every line and the table LOADED. Before each run it waits up to ``--load-wait``
seconds for the load to fall below ``--max-load`` and records the load each run started at.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_common  # noqa: E402
import policy_runs  # noqa: E402

BASELINE = "truav"


def run_once(scheme: str, scenario: Path, agents: int, rate: float, seconds: float, loaded: bool) -> dict:
    """One real-time run of ``scheme``; its figures."""
    ticks = max(1, int(round(seconds * rate)))
    load0 = os.getloadavg()[0]
    world, sampler, code, why = policy_runs.fly(scheme, scenario, agents, ticks, rate=rate, period_s=0.5,
                                           timeout_s=seconds * 4 + 300)
    t0, t1 = world.get("first_tick_wall_s"), world.get("last_tick_wall_s")
    cores = sampler.agent_cores(t0, t1) if t0 and t1 else float("nan")
    return {"scheme": scheme, "agents": agents, "rate_hz": rate, "ticks": int(world.get("ticks", ticks)),
            "exit_code": code, "why": why, "load_before": load0, "load_after": os.getloadavg()[0], "loaded": loaded,
            "missed_pct": policy_runs.missed_pct(world, agents),
            "tick_p99_ms": bench_common.tick_p99_ms(world),
            "agent_cores": cores, "cpu_pct_per_uav": 100.0 * cores / agents}


def line(r: dict) -> str:
    return (f"{'LOADED ' if r['loaded'] else ''}{r['scheme']:>6s} {r['agents']} UAVs {r['ticks']} ticks at "
            f"{r['rate_hz']:g} Hz, load {r['load_before']:.2f}: missed {r['missed_pct']:.3f}% of actions, tick "
            f"lateness p99 {r['tick_p99_ms']:.1f} ms, agents {r['agent_cores']:.3f} cores "
            f"({r['cpu_pct_per_uav']:.2f}% of a core per UAV), exit {r['exit_code']}"
            + (f"\n       exit {r['exit_code']}: {r['why']}" if r["exit_code"] else ""))


def table(rows: list[dict]) -> str:
    """Per scheme: runs, the medians, and the missed share over ``truav``'s."""
    keys = ("missed_pct", "tick_p99_ms", "agent_cores", "cpu_pct_per_uav", "load_before")
    schemes = list(dict.fromkeys(r["scheme"] for r in rows))
    med = {s: {k: float(np.median([r[k] for r in rows if r["scheme"] == s])) for k in keys} for s in schemes}
    base = med.get(BASELINE, {}).get("missed_pct")
    out = [("LOADED (measured beside other jobs: not the policies' cost)\n" if any(r["loaded"] for r in rows) else "")
           + f"| scheme | runs | load | missed % | x missed of {BASELINE} | tick lateness p99 ms | agent cores | "
             "% of a core per UAV |", "|---|---|---|---|---|---|---|---|"]
    for s, m in med.items():
        if s == BASELINE or base is None:
            ratio = "-"
        else:
            ratio = bench_common.ratio(m["missed_pct"], base, f"more ({BASELINE} missed 0)")
        out.append(f"| {s} | {sum(r['scheme'] == s for r in rows)} | {m['load_before']:.2f} | {m['missed_pct']:.3f} | "
                   f"{ratio} | {m['tick_p99_ms']:.1f} | {m['agent_cores']:.3f} | {m['cpu_pct_per_uav']:.2f} |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = bench_common.parser(__doc__)
    ap.add_argument("--agents", type=int, default=20, help="UAVs, each an agent process (default 20)")
    bench_common.add_tick_options(ap)
    ap.add_argument("--repeat", type=int, default=3, help="rounds of the schemes, alternated (default 3)")
    ap.add_argument("--schemes", default=f"{BASELINE},ppo", help="comma-separated: truav (the Q-learning agents) "
                    "or an agent name (default truav,ppo)")
    ap.add_argument("--quick", action="store_true", help="a smoke run: 4 UAVs, 5 s, 1 round")
    policy_runs.add_speed_option(ap)
    bench_common.add_load_options(ap)
    ap.add_argument("--json", type=Path, metavar="FILE", help="also write the rows as JSON")
    args = ap.parse_args(argv)
    if args.speed is not None and not 0.1 <= args.speed <= 100:
        print(f"bench_policy_realtime: error: --speed: a UAV speed in [0.1, 100] m/s, got {args.speed:g}", file=sys.stderr)
        return 2
    if args.quick:
        args.agents, args.seconds, args.repeat = 4, 5.0, 1
    schemes = [s for s in args.schemes.split(",") if s]
    if not schemes:
        print("bench_policy_realtime: error: --schemes: name at least one", file=sys.stderr)
        return 2
    if bench_common.refuse_nonpositive("bench_policy_realtime", args, ("--agents", "--seconds", "--rate", "--repeat")):
        return 2
    if args.agents > policy_runs.MAX_PROCESSES:
        print(f"bench_policy_realtime: error: --agents: at most {policy_runs.MAX_PROCESSES} agent processes in "
              f"real time", file=sys.stderr)
        return 2
    if bench_common.refuse_loaded("bench_policy_realtime", args):
        return 2
    rows: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="truav-bench-realtime-") as tmp:
        scenario = policy_runs.write_scenario(Path(tmp) / "paper-sense1500.toml", args.speed)
        for _ in range(args.repeat):
            for s in schemes:
                loaded = bench_common.wait_for_load(args)
                try:
                    r = run_once(s, scenario, args.agents, args.rate, args.seconds, loaded)
                except RuntimeError as exc:
                    print(f"bench_policy_realtime: {exc}", file=sys.stderr)
                    return 1
                rows.append(r)
                print(line(r), flush=True)
    print(table(rows))
    bench_common.write_rows(args.json, rows)
    failed = sum(r["exit_code"] != 0 for r in rows)
    if failed:
        print(f"bench_policy_realtime: {failed} run(s) did not end ok (exit code above)", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())

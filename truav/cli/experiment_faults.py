"""`truav experiment faults`: its parser and command (the sweep itself is
truav.swarm.fault_sweep, the scheme comparison truav.swarm.scheme_faults).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from truav import jsonio
from truav.analysis import policy_scenario
from truav.cli.args import check_out_dir, positive_float, seed_int
from truav.cli.config import UsageError, add_config_args, config_from, parse_sets
from truav.cli.experiment_executor import add_executor_args, check_executor
from truav.config import ConfigError, read_toml, to_dict
from truav.swarm import fault_sweep
from truav.swarm.scheme_faults import SCHEMES


def add_fault_sweep_parser(ex_sub) -> None:
    """`truav experiment faults` in the experiment command group."""
    p = ex_sub.add_parser("faults", help="swarm metrics against beacon loss (0-50%%) and latency (0-500 ms)")
    add_config_args(p)
    p.add_argument("--quick", action="store_true",
                   help="3 levels each, 3 short episodes per point (the effects paired over them; about 3 minutes per "
                        "scheme at the default rate, more at a lower --rate); "
                        "default: the full sweep")
    p.add_argument("--qtable", metavar="RUN", help="fly this trained run's policy (default: train one first)")
    policy_scenario.add_allow_arg(p)
    p.add_argument("--seed", type=seed_int, default=0, help="seed of every swarm run (default %(default)s)")
    p.add_argument("--rate", type=positive_float, default=10.0, help="tick rate in Hz (default %(default)g)")
    p.add_argument("--out", help="output directory (default runs/faults[-quick]); re-running with the same "
                                 "options resumes (other options are refused)")
    p.add_argument("--schemes", nargs="+", metavar="SCHEME",
                   help=f"compare these schemes under the same link loss, latency, process crash and partition "
                        f"(the first half of the UAVs cut off from the rest) levels: "
                        f"{', '.join(SCHEMES)}, or an agent class (pkg.module:Class or a name registered in the "
                        f"entry-point group truav.agents: trained in process, then flown greedily; spread is the "
                        f"decentralized heuristic, flown with its sensing on, the bar a learner must clear) "
                        "(truav.swarm.scheme_faults: comparison.csv, comparison-<metric>.png); "
                        "federated and truav_online fly the TRUAV table learning online, with and without "
                        "Q-sharing (federated.every, 1 unless set); "
                        "default: the TRUAV beacon sweep (faults.csv, faults.png)")
    p.add_argument("--policy", metavar="RUN", help="with --schemes central: the controller's trained actor "
                                                   "(`truav train --scheme central`; default: train one first)")
    add_executor_args(p)
    p.set_defaults(func=cmd_fault_sweep)


def cmd_fault_sweep(args) -> int:
    size = "quick" if args.quick else "full"
    cfg = config_from(args)
    out = check_out_dir("--out", args.out if args.out is not None else f"runs/faults{'-quick' if args.quick else ''}")
    fits = []
    if args.qtable is not None:  # the policy every swarm run flies: check it fits before the first run
        from truav.swarm.checks import check_qtable
        fits.append(check_qtable("--qtable", args.qtable, cfg, allow_mismatch=args.allow_scenario_mismatch))
    if args.policy is not None and "central" in (args.schemes or ()):
        from truav.swarm.checks import check_policy
        fits.append(check_policy("--policy", args.policy, cfg, 0, args.allow_scenario_mismatch))
    check_executor(args)
    given = [parse_sets(args.set)] + ([read_toml(args.config, "config file", ConfigError)] if args.config else [])
    keep_steps = any("steps_per_episode" in (layer.get("scenario") or {}) for layer in given)  # the user's wins
    settings = {"mode": "schemes" if args.schemes else "sweep", "size": size, "seed": args.seed, "rate": args.rate,
                "qtable": _resolved(args.qtable), "policy": _resolved(args.policy), "keep_steps": keep_steps,
                "config": to_dict(cfg)}
    if any(f.line() for f in fits):  # a mismatch allowed, or a record missing: in settings.json and said
        settings["policy_scenario"] = [f.as_json() for f in fits]
        for fit in fits:
            if fit.line():
                print(f"warning: {fit.line()}", flush=True)
    if args.schemes:
        from truav.swarm.scheme_faults import run_comparison
        schemes = tuple(dict.fromkeys(args.schemes))
        for name in schemes:  # an agent class: found and checked (one line, exit 2) before anything runs
            if name not in SCHEMES:
                from truav.analysis import agent_loader
                agent_loader.load(name, cfg, flag="--schemes")
        if args.policy is not None:
            if "central" not in schemes:
                raise UsageError("--policy: only --schemes central flies a trained controller")
        if "central" in schemes:
            from truav.swarm.checks import check_central_sizes
            check_central_sizes(cfg)
        check_settings(out, settings)
        return _sweep(lambda: run_comparison(cfg, size, out, schemes, seed=args.seed, qtable=args.qtable,
                                             policy=args.policy, rate_hz=args.rate, keep_steps=keep_steps,
                                             executor=args.executor, address=args.address),
                      [out / "comparison.csv"])
    if args.policy is not None:
        raise UsageError("--policy: only with --schemes central")
    check_settings(out, settings)
    return _sweep(lambda: [fault_sweep.run_sweep(cfg, size, out, seed=args.seed, qtable=args.qtable,
                                                 rate_hz=args.rate, keep_steps=keep_steps, executor=args.executor,
                                                 address=args.address)], [out / "faults.csv"])


def _sweep(run, first: list[Path]) -> int:
    """Run a sweep; its files, or one line on a stop signal (exit 128 + it) or a failed point (exit 1). The
    points finished before are kept either way: the same command runs the rest."""
    try:
        paths = run()
    except fault_sweep.PointInterrupted as exc:
        print(f"truav: {exc}; run the same command to resume", file=sys.stderr, flush=True)
        return exc.code
    except fault_sweep.PointFailed as exc:
        print(f"truav: error: {exc}; the points before it are kept: run the same command to resume",
              file=sys.stderr, flush=True)
        return 1
    print("\n" + "\n".join(map(str, [*first, *paths])))
    return 0


SETTINGS_FILE = "settings.json"
"""In --out: the settings its points were run with (a re-run resumes only with the same ones)."""


def _resolved(path: str | None) -> str | None:
    return None if path is None else str(Path(path).resolve())


def check_settings(out: Path, settings: dict) -> None:
    """A re-run into ``out`` keeps its finished points, so it must run with their settings: the first run writes
    them to SETTINGS_FILE, a later one with others is refused in one line (UsageError) before anything runs."""
    path = out / SETTINGS_FILE
    settings = json.loads(jsonio.dumps(settings))  # tuples as lists, as read back
    if path.is_file():
        try:
            before = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise UsageError(f"--out {out}: {path.name} is unreadable ({exc}); choose another --out") from None
        differ = [k for k in settings if not isinstance(before, dict) or before.get(k) != settings[k]]
        if differ:
            raise UsageError(f"--out {out}: holds points run with other settings ({', '.join(differ)} differ from "
                             f"{path}); use the same options to resume them, or another --out")
        return
    if any(out.glob("*/summary.json")):
        raise UsageError(f"--out {out}: holds finished points with no {path.name} to tell their settings (an "
                         f"earlier version's run); choose another --out")
    out.mkdir(parents=True, exist_ok=True)
    path.write_text(jsonio.dumps(settings, indent=1))

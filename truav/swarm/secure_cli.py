"""`truav-swarm certs` and `truav-swarm acl explain`: the security material of a locked bus.

    truav-swarm certs --out creds --run demo --agents 5 -e tcp/10.0.0.1:7447 --host router.lan
    truav-swarm router --creds creds            # mutual TLS + access control, from creds/router.json5
    truav-swarm world --run demo --creds creds  # each part with its own certificate
    truav-swarm acl explain --creds creds --identity 'uav/1'
    truav-swarm acl explain --run demo --agents 5 --key truav/demo/control/shutdown
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from truav.bus import keys, security
from truav.cli import UsageError
from truav.cli_args import positive_int


def _table(args) -> tuple[security.Grant, ...]:
    if args.creds:
        try:
            return security.load(args.creds).table()
        except security.CredentialsError as exc:
            raise UsageError(str(exc)) from None
    try:
        keys.validate_run(args.run)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    return security.grants(args.run, args.agents)


def cmd_certs(args) -> int:
    out = Path(args.out)
    if out.exists() and any(out.iterdir()) and not args.force:
        raise UsageError(f"--out {out} is not empty; choose another directory or pass --force")
    try:
        keys.validate_run(args.run)
        security.issue(out, args.run, args.agents, args.connect, hosts=[*security.DEFAULT_HOSTS, *args.host],
                       days=args.days)
    except (ValueError, OSError) as exc:
        raise UsageError(str(exc)) from None
    creds = security.load(out)
    print(f"credentials for run {creds.run!r} ({creds.n_uavs} agents, router at {creds.endpoint}) in {out}:")
    print(f"  ca.pem (trust anchor), ca.key (keep private: it signs new certificates), router.json5, "
          f"one <identity>.key/.pem/.json5 per component")
    print(f"  start the router with `truav-swarm router --creds {out}`, every part with `--creds {out}`")
    return 0


def cmd_acl(args) -> int:
    table = _table(args)
    if args.json:
        print(json.dumps(security.acl_config(table), indent=1))
        return 0
    try:
        lines = security.explain(table, args.identity, args.key)
    except security.CredentialsError as exc:
        raise UsageError(str(exc)) from None
    print("\n".join(lines))
    return 0


def add_security_commands(sub) -> None:
    ce = sub.add_parser("certs", help="create a CA, one certificate per component and the router's access control")
    ce.add_argument("--out", required=True, metavar="DIR", help="credentials directory to create")
    ce.add_argument("--run", default="demo", help="run the access control is written for (default demo)")
    ce.add_argument("--agents", type=positive_int, default=5, help="number of UAV agents (default 5)")
    ce.add_argument("-e", "--connect", default="tcp/127.0.0.1:7447", metavar="ENDPOINT",
                    help="where the router listens and clients connect (made tls/; default tcp/127.0.0.1:7447)")
    ce.add_argument("--host", action="append", default=[], metavar="NAME",
                    help="extra host name or IP of the router for its certificate (repeatable; "
                         "localhost and 127.0.0.1 always)")
    ce.add_argument("--days", type=positive_int, default=security.DEFAULT_VALID_DAYS,
                    help=f"validity of the certificates in days (default {security.DEFAULT_VALID_DAYS})")
    ce.add_argument("--force", action="store_true", help="write into a non-empty directory")
    ce.set_defaults(func=cmd_certs)

    acl = sub.add_parser("acl", help="explain the access control: which identity may put or subscribe where")
    acl_sub = acl.add_subparsers(dest="acl_command", required=True, metavar="ACTION")
    ex = acl_sub.add_parser("explain", help="list what each identity may do (or who may use one key)",
                            formatter_class=argparse.RawDescriptionHelpFormatter)
    ex.add_argument("--creds", metavar="DIR", help="a credentials directory (its run and agent count)")
    ex.add_argument("--run", default="demo", help="run, without --creds (default demo)")
    ex.add_argument("--agents", type=positive_int, default=5, help="number of agents, without --creds (default 5)")
    ex.add_argument("--identity", metavar="ID", help="only this identity (shell pattern, e.g. 'uav/*')")
    ex.add_argument("--key", metavar="KEY", help="for one concrete key: who may put / subscribe / watch it")
    ex.add_argument("--json", action="store_true", help="print the router's access_control section instead")
    ex.set_defaults(func=cmd_acl)


REJECTED_METRIC = "rejected"
"""Step-metrics value: messages the world refused so far; ``rejected.<reason>`` per reason."""


def rejection_metrics(rejections) -> dict[str, float]:
    """The world's step-metrics values for its :class:`~truav.bus.guard.Rejections` (bounded: one per reason)."""
    by_reason = rejections.by_reason()
    return {REJECTED_METRIC: float(sum(by_reason.values())),
            **{f"{REJECTED_METRIC}.{reason}": float(n) for reason, n in by_reason.items()}}


def rejections_heard(bus, run: str | None):
    """Listen to step metrics; the returned function gives one line per run whose world refused messages."""
    import threading
    latest: dict[str, dict[str, float]] = {}
    lock = threading.Lock()

    def on_step(key, msg, raw, recv_ns) -> None:
        with lock:
            latest[keys.parse_run(key) or "?"] = dict(msg.values)

    bus.subscribe(keys.metrics_step(run) if run else f"{keys.ROOT}/*/metrics/step", on_step)

    def lines(wait_s: float = 0.0) -> list[str]:
        import time
        deadline = time.monotonic() + wait_s
        while not latest and time.monotonic() < deadline:  # the world publishes step metrics every tick
            time.sleep(0.02)
        with lock:
            seen = dict(latest)
        out = []
        for r, values in sorted(seen.items()):
            total = int(values.get(REJECTED_METRIC, 0))
            reasons = ", ".join(f"{k.split('.', 1)[1]} {int(v)}" for k, v in sorted(values.items())
                                if k.startswith(REJECTED_METRIC + "."))
            out.append(f"run {r}: the world rejected {total} message(s)" + (f" ({reasons})" if reasons else ""))
        return out

    return lines

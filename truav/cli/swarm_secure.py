"""`truav-swarm certs` and `truav-swarm acl explain`: the security material of a locked bus.

    truav-swarm certs --out creds --run demo --agents 5 -e tcp/10.0.0.1:7447 --host router.lan
    truav-swarm router --creds creds            # mutual TLS + access control, from creds/router.json5
    truav-swarm world --run demo --creds creds  # each part with its own certificate
    truav-swarm acl explain --creds creds --identity 'uav/1'
    truav-swarm acl explain --run demo --agents 5 --key truav/demo/control/shutdown

and for a router per host (deploy/README.md):

    truav-swarm certs --deployment deploy/three-hosts.toml --out creds     # creds/<host>/ per host, ca.key in creds/
    truav-swarm deploy-configs deploy/three-hosts.toml --out deploy/three-hosts   # the same configs, no keys
"""

from __future__ import annotations

import argparse
from pathlib import Path

from truav import jsonio
from truav.bus import security
from truav.bus.rejections import REJECTED_METRIC  # the world's step-metrics key, read back here
from truav.checks import check_out_dir
from truav.cli.args import positive_int
from truav.cli.config import UsageError
from truav.wire import keys
from world.world_stats import uav_metrics  # the world's per-UAV step-metrics values, read back here


def _table(args) -> tuple[tuple[security.Grant, ...], tuple[str, ...]]:
    """The grants and the peer routers (a host's bundle) to explain."""
    if args.creds:
        try:
            creds = security.load(args.creds)
        except security.CredentialsError as exc:
            raise UsageError(str(exc)) from None
        return creds.table(), creds.peer_routers
    try:
        keys.validate_run(args.run)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    return security.grants(args.run, args.agents), ()


def _empty_out(args) -> Path:
    out = check_out_dir("--out", args.out)  # a directory that exists or can be made
    if out.exists() and any(out.iterdir()) and not args.force:
        raise UsageError(f"--out {out} is not empty; choose another directory or pass --force")
    return out


def cmd_certs(args) -> int:
    out = _empty_out(args)
    if args.deployment:
        return _certs_per_host(args, out)
    args.run = "demo" if args.run is None else args.run
    args.agents = 5 if args.agents is None else args.agents
    args.connect = "tcp/127.0.0.1:7447" if args.connect is None else args.connect
    try:
        keys.validate_run(args.run)
        security.issue(out, args.run, args.agents, args.connect, hosts=[*security.DEFAULT_HOSTS, *args.host],
                       days=args.days)
    except OSError as exc:  # the directory cannot be made or written
        raise UsageError(f"--out {out}: cannot write the credentials there ({exc.strerror or exc})") from None
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    creds = security.load(out)
    print(f"credentials for run {creds.run!r} ({creds.n_uavs} agents, router at {creds.endpoint}) in {out}:")
    print("  ca.pem (trust anchor), ca.key (keep private: it signs new certificates), router.json5, "
          "one <identity>.key/.pem/.json5 per component")
    print(f"  start the router with `truav-swarm router --creds {out}`, every part with `--creds {out}`")
    return 0


def _certs_per_host(args, out: Path) -> int:
    from truav.swarm import deploy
    given = [flag for flag, value in (("--run", args.run), ("--agents", args.agents), ("-e/--connect", args.connect),
                                      ("--host", args.host or None)) if value is not None]
    if given:
        raise UsageError(f"{given[0]}: comes from --deployment {args.deployment}; drop it")
    plan = deploy.load(args.deployment)
    try:
        security.issue(out, plan.run, plan.agents, sites=plan.sites(), days=args.days)
    except (ValueError, OSError) as exc:
        raise UsageError(str(exc)) from None
    print(f"credentials for run {plan.run!r} ({plan.agents} agents, {len(plan.hosts)} hosts) in {out}:")
    print(f"  {out}/ca.key: the CA key, in no bundle: keep it here (it signs new certificates) or delete it")
    for h in plan.hosts:
        print(f"  {out}/{h.name}/  -> host {h.name} ({h.address}): router, {', '.join(h.runs) or 'no component'}")
    print("  copy each bundle to its host (e.g. scp -r), then start its router with `truav-swarm router --creds DIR` "
          "and every part with `--creds DIR` (deploy/README.md)")
    return 0


def cmd_deploy_configs(args) -> int:
    from truav.swarm import deploy
    out = _empty_out(args)
    plan = deploy.load(args.deployment, "deployment file")
    try:
        configs = security.site_configs(plan.run, plan.agents, plan.sites())
        for host, files in configs.items():
            security.write_configs(out / host, files)
    except (ValueError, OSError) as exc:
        raise UsageError(str(exc)) from None
    print(f"zenoh configs of {len(configs)} hosts in {out}/<host>/ (no keys; `truav-swarm certs --deployment "
          f"{args.deployment}` writes the same with the keys, and each config with its files inline)")
    return 0


def cmd_acl(args) -> int:
    table, peers = _table(args)
    if args.json:
        print(jsonio.dumps(security.acl_config(table, peers), indent=1))
        return 0
    try:
        lines = security.explain(table, args.identity, args.key, peers)
    except security.CredentialsError as exc:
        raise UsageError(str(exc)) from None
    print("\n".join(lines))
    return 0


def add_security_commands(sub) -> None:
    ce = sub.add_parser("certs", help="create a CA, one certificate per component and the router's access control")
    ce.add_argument("--out", required=True, metavar="DIR", help="credentials directory to create")
    ce.add_argument("--deployment", metavar="FILE",
                    help="a router per host (deploy/three-hosts.toml): one bundle DIR/<host>/ per host with only "
                         "that host's keys; the run, agents and addresses come from FILE")
    ce.add_argument("--run", help="run the access control is written for (default demo)")
    ce.add_argument("--agents", type=positive_int, help="number of UAV agents (default 5)")
    ce.add_argument("-e", "--connect", metavar="ENDPOINT",
                    help="where the router listens and clients connect (made tls/; default tcp/127.0.0.1:7447)")
    ce.add_argument("--host", action="append", default=[], metavar="NAME",
                    help="extra host name or IP of the router for its certificate (repeatable; "
                         "localhost and 127.0.0.1 always)")
    ce.add_argument("--days", type=positive_int, default=security.DEFAULT_VALID_DAYS,
                    help=f"validity of the certificates in days (default {security.DEFAULT_VALID_DAYS})")
    ce.add_argument("--force", action="store_true", help="write into a non-empty directory")
    ce.set_defaults(func=cmd_certs)

    dc = sub.add_parser("deploy-configs", help="write the zenoh configs of a multi-host deployment (no keys)")
    dc.add_argument("deployment", metavar="FILE", help="deployment file (deploy/three-hosts.toml)")
    dc.add_argument("--out", required=True, metavar="DIR", help="directory for <host>/router.json5 and the clients'")
    dc.add_argument("--force", action="store_true", help="write into a non-empty directory")
    dc.set_defaults(func=cmd_deploy_configs)

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


MAX_HEALTH_SHOWN = 1024
"""Agents' health reports `status` keeps (one per run and UAV id, the newest): bounded whatever is sent."""


def rejections_heard(bus, run: str | None):
    """Listen to the world's step metrics and the agents' health reports; the returned function
    ``lines(wait_s, agents)`` gives one line per run whose world refused messages and one per agent
    heard. It waits up to ``wait_s`` for the world's metrics and for a report of every agent in
    ``agents`` (liveliness token keys; agents report about once a second)."""
    import threading
    worlds: dict[str, dict[str, float]] = {}
    agents: dict[tuple[str, int], object] = {}
    lock = threading.Lock()

    def on_step(key, msg, raw, recv_ns) -> None:
        with lock:
            worlds[keys.parse_run(key) or "?"] = dict(msg.values)

    def on_health(key, msg, raw, recv_ns) -> None:
        if msg.src != keys.uav_identity(msg.uav):  # status has no scenario guard: this check is the guard's
            return
        where = (keys.parse_run(key) or "?", msg.uav)
        with lock:
            if where in agents or len(agents) < MAX_HEALTH_SHOWN:
                agents[where] = msg

    pattern = keys.prefix(run) if run else f"{keys.ROOT}/*"
    bus.subscribe(f"{pattern}/metrics/step", on_step)
    bus.subscribe(f"{pattern}/uav/*/{keys.HEALTH}", on_health)

    def lines(wait_s: float = 0.0, alive: list[str] = ()) -> list[str]:
        import time
        want = {(keys.parse_run(k) or "?", keys.parse_uav_id(k)) for k in alive if keys.parse_uav_id(k) is not None}
        deadline = time.monotonic() + wait_s
        while time.monotonic() < deadline:  # step metrics come every tick, health reports every second
            with lock:
                if worlds and want <= agents.keys():
                    break
            time.sleep(0.02)
        with lock:
            seen, reports = dict(worlds), dict(agents)
        out = []
        for r, values in sorted(seen.items()):
            total = int(values.get(REJECTED_METRIC, 0))
            reasons = ", ".join(f"{k.split('.', 1)[1]} {int(v)}" for k, v in sorted(values.items())
                                if k.startswith(REJECTED_METRIC + "."))
            out.append(f"run {r}: the world rejected {total} message(s)" + (f" ({reasons})" if reasons else ""))
            per_uav = uav_metrics(values)  # the world's worst UAVs (missed, late, stale, rejected), bounded
            if per_uav:
                out.append(f"run {r}: per UAV (worst first): " + "; ".join(
                    f"uav {u} " + " ".join(f"{k} {n}" for k, n in sorted(c.items()))
                    for u, c in sorted(per_uav.items(), key=lambda uc: (-sum(uc[1].values()), uc[0]))))
        for (r, uav), h in sorted(reports.items()):
            out.append(health_line(r, h))
        return out

    return lines


def health_line(run: str, h) -> str:
    """One agent's health report as `status` shows it."""
    total = sum(h.rejected.values())
    reasons = ", ".join(f"{k} {v}" for k, v in sorted(h.rejected.items()))
    senders = ", ".join(f"{k} {v}" for k, v in sorted(h.senders.items(), key=lambda kv: (-kv[1], kv[0])))
    line = f"run {run}: uav {h.uav} rejected {total} message(s)" + (f" ({reasons}; from {senders})" if total else "")
    line += f", last tick {h.last_tick}, {h.steps} steps"
    return line + (f", {h.stale_obs_skipped} stale observation(s) skipped" if h.stale_obs_skipped else "")

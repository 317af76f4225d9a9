"""`truav-swarm status|down|faults|view`: commands that talk to a running swarm.

status lists who is alive, down asks the swarm to stop (then signals what still runs), faults
replaces a running swarm's fault plan, view serves a run to the Foxglove app. Without -e they
find the run's router in its output directory's swarm.json.
"""

from __future__ import annotations

import logging
import os
import threading
from pathlib import Path

from truav.bus.fault_filter import CONTROL_FAULTS
from truav.bus.transport import Bus
from truav.checks import check_endpoint, check_in_file, check_out_dir
from truav.cli.args import UserError, positive_float, run_name, tcp_port
from truav.cli.config import UsageError
from truav.faults import load_plan
from truav.lifecycle import stop_on_sigterm_or_orphaned
from truav.cli.args import check_tls_creds
from truav.wire import keys, schema
from truav.cli.swarm_common import (add_geo_origin_arg, add_scenario_args, add_transport_args, config_from_args, part_creds,
                                    scenario_from, setup_logging)
from truav.cli.swarm_secure import rejections_heard
from truav.swarm.children import stop_recorded_pids
from truav.swarm.outdir import RUN_FILE, SUMMARY_FILE, read_run_file
from truav.swarm.swarm_options import DOWN_IDENTITY, default_out_dir

log = logging.getLogger("truav.swarm")


def _pid_running(pid) -> bool:
    """Whether process ``pid`` exists (one of another user's counts; a zombie does not)."""
    if not isinstance(pid, int) or isinstance(pid, bool) or pid <= 0:
        return True  # unknown: do not call the run ended on a guess
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        except OSError:
            return True
        return True


def _endpoint_from_out(args, out: Path | None, explicit: bool, need_run: bool = False) -> None:
    """Without -e, connect where the run writing ``out`` has its router (from its swarm.json). An --out
    the user named (or, with ``need_run``, the default one) must hold one: connecting to the default
    endpoint instead would be a silent guess. A run that has ended (its summary written, or its
    supervisor gone) is said to have ended, not looked for on a router that is no longer there."""
    if args.connect or args.config or getattr(args, "creds", None) or out is None:  # --creds has its router
        return
    info = read_run_file(out)
    if info and isinstance(info, dict) and isinstance(info.get("endpoint"), str) and info["endpoint"]:
        check_endpoint(f"{out / RUN_FILE}: endpoint", info["endpoint"])
        run = info.get("run") if isinstance(info.get("run"), str) else args.run
        if (out / SUMMARY_FILE).is_file():  # written when a run ends; removed when one starts
            raise UserError(f"run {run!r} in {out} has ended ({out / SUMMARY_FILE} holds its summary): "
                            f"nothing of it is running")
        if not _pid_running(info.get("supervisor_pid")):
            raise UserError(f"run {run!r} in {out} has ended (its supervisor, PID {info['supervisor_pid']} "
                            f"in {out / RUN_FILE}, is not running)")
        args.connect = [info["endpoint"]]
    elif explicit:
        raise UserError(f"--out {out}: no swarm run's {RUN_FILE} with its router endpoint there "
                        f"(a directory `truav-swarm up --out` wrote); or give -e/--connect ENDPOINT")
    elif need_run:
        raise UserError(f"--run {args.run}: no such run: {out / RUN_FILE} does not exist (`truav-swarm up "
                        f"--run {args.run}` writes it); for a run with another --out pass --out DIR, or "
                        f"-e/--connect ENDPOINT")
    check_tls_creds(args, f"{out / RUN_FILE}: endpoint")


def cmd_status(args) -> int:
    if args.out is not None:
        check_out_dir("--out", args.out)
    _endpoint_from_out(args, Path(args.out) if args.out else None, explicit=args.out is not None)
    part_creds(args, "supervisor")
    conf = config_from_args(args)
    pattern = keys.all_alive(args.run) if args.run else "truav/*/alive/**"
    with Bus("status", args.run or "status", conf) as bus:
        heard = rejections_heard(bus, args.run)
        tokens = sorted(bus.alive(pattern, timeout=args.timeout))
        # Agents report once a second (agents.process.agent_process.HEALTH_PERIOD_S): wait a little longer for theirs.
        rejected = heard(min(args.timeout, 0.5) + 1.2 if tokens else 0.0, tokens)
    if not tokens:
        print("no TRUAV process alive" + (f" in run {args.run}" if args.run else ""))
        return 1
    for token in tokens:
        print(token)
    for line in rejected:
        print(line)
    return 0


DOWN_LISTENER_WAIT_S = 5.0
"""How long `down` waits for the run's processes to be known as listeners before it sends."""


def cmd_down(args) -> int:
    if args.out is not None:
        check_out_dir("--out", args.out)
    out = Path(args.out) if args.out else default_out_dir(args.run)
    _endpoint_from_out(args, out, explicit=args.out is not None, need_run=True)
    part_creds(args, "supervisor")
    with Bus(DOWN_IDENTITY, args.run, config_from_args(args)) as bus:
        key = keys.control(args.run, "shutdown")
        if not bus.await_subscribers(key, DOWN_LISTENER_WAIT_S):
            log.warning("no process of run %s listens for its shutdown (yet); sending it anyway", args.run)
        bus.publish(key, schema.Control(command="shutdown", args={}))
    # The swarm stops itself on the shutdown (its supervisor stops the router and recorder last);
    # only what still runs after a while is signalled, from the pid file.
    stopped = stop_recorded_pids(out, wait_s=args.wait)
    print(f"shutdown sent to run {args.run}" + (f"; {stopped} process(es) still running after {args.wait:g} s "
                                                 f"were sent SIGTERM (from {out}/pids.json)" if stopped else ""))
    return 0


def cmd_faults(args) -> int:
    check_in_file("--plan", args.plan)
    plan = load_plan(args.plan)
    on_processes = sorted({f.kind for f in plan.faults if f not in plan.link_faults})
    if on_processes:  # sent along, they would be dropped by every receiver: the user would think them applied
        raise UsageError(f"--plan {args.plan}: {' and '.join(on_processes)} faults act on processes, which only "
                         f"`truav-swarm up --fault-plan` schedules; `faults` replaces a running swarm's link faults "
                         f"(remove them from this plan)")
    part_creds(args, "supervisor")
    with Bus("supervisor", args.run, config_from_args(args)) as bus:
        key = keys.control(args.run, CONTROL_FAULTS)
        if not bus.await_subscribers(key, DOWN_LISTENER_WAIT_S):
            log.warning("no process of run %s listens for fault plans (yet); sending it anyway", args.run)
        bus.publish(key, schema.Control(command=CONTROL_FAULTS, args=plan.to_dict()))
    print(f"sent a plan of {len(plan.link_faults)} link fault(s) to run {args.run}"
          + (" (an empty plan: every link fault of the run is cleared)" if not plan.link_faults else ""))
    return 0


def cmd_view(args) -> int:
    from recorder.foxglove import FoxgloveMirror, Geometry
    from truav.swarm.view import serve
    setup_logging(args.verbose)
    cfg = scenario_from(args)
    stop = threading.Event()
    stop_on_sigterm_or_orphaned(stop.set)
    mirror = FoxgloveMirror(Geometry.from_config(cfg), args.geo_origin)

    def ready(port: int) -> None:
        print(f"Foxglove: open ws://127.0.0.1:{port} (run {args.run}); layout: deploy/foxglove-layout.json",
              flush=True)

    part_creds(args, "view")
    try:
        serve(args.run, config_from_args(args), mirror, port=args.port, stop=stop, ready=ready)
    except KeyboardInterrupt:
        pass
    except RuntimeError as exc:  # the SDK's server could not bind (port in use)
        raise UsageError(f"--port {args.port}: the Foxglove server could not start ({exc})") from None
    return 0




def add_ops_commands(sub) -> None:
    """The `faults`, `status`, `down` and `view` subcommands (in that order: `--help` lists them so)."""
    fa = sub.add_parser("faults", help="replace the fault plan of a running swarm (link faults)")
    fa.add_argument("--run", type=run_name, default="demo")
    fa.add_argument("--plan", required=True, metavar="FILE", help="fault plan TOML; an empty file clears all faults")
    add_transport_args(fa)
    fa.set_defaults(func=cmd_faults)

    st = sub.add_parser("status", help="who is alive (from liveliness tokens)")
    st.add_argument("--run", type=run_name, help="only this run")
    st.add_argument("--timeout", type=positive_float, default=1.0,
                    help="seconds to wait for the swarm's liveliness tokens (default 1)")
    st.add_argument("--out", help="connect to the router of the run writing this directory (its swarm.json)")
    add_transport_args(st)
    st.set_defaults(func=cmd_status)

    dn = sub.add_parser("down", help="ask a running swarm to shut down")
    dn.add_argument("--run", type=run_name, default="demo")
    dn.add_argument("--out", help="the swarm's output directory with swarm.json and pids.json "
                                  "(default runs/swarm-<run>; gives the endpoint when -e is not given)")
    dn.add_argument("--wait", type=positive_float, default=30.0, metavar="S",
                    help="seconds to let the swarm stop itself before signalling what still runs (default 30)")
    add_transport_args(dn)
    dn.set_defaults(func=cmd_down)

    vw = sub.add_parser("view", help="serve a live run or a replay to the Foxglove app (WebSocket, loopback)")
    add_scenario_args(vw)
    vw.add_argument("--port", type=tcp_port, default=8765, help="WebSocket port on 127.0.0.1 (default 8765; 0: any)")
    add_geo_origin_arg(vw)
    vw.add_argument("-v", "--verbose", action="store_true")
    add_transport_args(vw)
    vw.set_defaults(func=cmd_view)

"""`truav-swarm status|down|faults|view`: commands that talk to a running swarm.

status lists who is alive, down asks the swarm to stop (then signals what still runs), faults
replaces a running swarm's fault plan, view serves a run to the Foxglove app. status, down and faults
find the run by --out DIR or --run NAME (truav.cli.run_lookup), never by a default port.
"""

from __future__ import annotations

import logging
import sys
import threading

from truav.bus.fault_filter import CONTROL_FAULTS
from truav.bus.transport import Bus
from truav.checks import check_in_file
from truav.cli.args import positive_float, tcp_port
from truav.cli.config import UsageError
from truav.faults import load_plan
from truav.lifecycle import stop_on_sigterm_or_orphaned
from truav.wire import keys, schema
from truav.cli.swarm_common import (add_geo_origin_arg, add_scenario_args, add_transport_args, config_from_args, part_creds,
                                    scenario_from, setup_logging)
from truav.cli.swarm_secure import rejections_heard
from truav.swarm.children import stop_recorded_pids
from truav.cli.run_lookup import OUT_HELP, add_run_args, explicit_router, find_run, run_there
from truav.swarm.swarm_options import DOWN_IDENTITY

log = logging.getLogger("truav.swarm")


def cmd_status(args) -> int:
    find_run(args)
    part_creds(args, "supervisor")
    conf = config_from_args(args)
    with Bus("status", args.run, conf) as bus:
        heard = rejections_heard(bus, args.run)
        tokens, missing = run_there(bus, args, args.timeout)
        # Agents report once a second (agents.process.agent_process.HEALTH_PERIOD_S): wait a little longer for theirs.
        rejected = heard(min(args.timeout, 0.5) + 1.2 if tokens else 0.0, tokens)
    if missing:
        print(f"truav-swarm: error: {missing}", file=sys.stderr)
        return 1
    for token in tokens:
        print(token)
    for line in rejected:
        print(line)
    return 0


DOWN_LISTENER_WAIT_S = 5.0
"""How long `down` waits for the run's processes to be known as listeners before it sends."""


def _reached(bus, args) -> bool:
    """Whether the router reached serves the run named (said in one line when not). Through an explicit
    router nothing of the run is a refusal too; from the run's own swarm.json (its supervisor holds the
    directory) a run still starting may have no token yet: then it is sent all the same."""
    tokens, missing = run_there(bus, args, 1.0)
    if missing and (explicit_router(args) or "serves run(s)" in missing):
        print(f"truav-swarm: error: {missing}", file=sys.stderr)
        return False
    return True


def cmd_down(args) -> int:
    out = find_run(args)
    part_creds(args, "supervisor")
    with Bus(DOWN_IDENTITY, args.run, config_from_args(args)) as bus:
        if not _reached(bus, args):
            return 1
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
    find_run(args)
    part_creds(args, "supervisor")
    with Bus("supervisor", args.run, config_from_args(args)) as bus:
        if not _reached(bus, args):
            return 1
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
    add_run_args(fa)
    fa.add_argument("--plan", required=True, metavar="FILE", help="fault plan TOML; an empty file clears all faults")
    add_transport_args(fa)
    fa.set_defaults(func=cmd_faults)

    st = sub.add_parser("status", help="who is alive (from liveliness tokens)")
    add_run_args(st)
    st.add_argument("--timeout", type=positive_float, default=1.0,
                    help="seconds to wait for the swarm's liveliness tokens (default 1)")
    add_transport_args(st)
    st.set_defaults(func=cmd_status)

    dn = sub.add_parser("down", help="ask a running swarm to shut down")
    add_run_args(dn, out_help=OUT_HELP + "; its pids.json names what to signal should the run not stop itself")
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

    from truav.cli.swarm_steer import add_steer_command
    add_steer_command(sub)

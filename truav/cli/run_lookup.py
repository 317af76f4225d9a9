"""How `status`, `down`, `faults` and `replay-ctl` find the run they act on: by its directory (--out DIR)
or its name (--run NAME: the directory `up --run NAME` writes without --out), whose swarm.json gives the
run's router; never by a default port, where another user's swarm may be. An explicit router (-e, -c,
--creds) is kept, and then the run named must be the one found there (:func:`run_there`).
"""

from __future__ import annotations

import os
from pathlib import Path

from truav.checks import check_endpoint, check_out_dir
from truav.cli.args import UserError, check_tls_creds
from truav.swarm import runlock
from truav.swarm.outdir import RUN_FILE, SUMMARY_FILE, read_run_file
from truav.swarm.swarm_options import default_out_dir

DEFAULT_RUN = "demo"
OTHER_RUNS_WAIT_S = 0.5
"""How long a command that found nothing of its run asks which runs the router does serve."""


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


def explicit_router(args) -> bool:
    return bool(args.connect or args.config or getattr(args, "creds", None))


def find_run(args) -> Path:
    """Set ``args.run`` (and, without an explicit router, ``args.connect``) to the run named by --out or
    --run (default demo); the run's directory. One line (UserError, exit 2) when there is no such run,
    it has ended, or --out holds another run than --run names."""
    if args.out is not None:
        check_out_dir("--out", args.out)
    out = Path(args.out) if args.out is not None else default_out_dir(args.run or DEFAULT_RUN)
    info = read_run_file(out)
    info = info if isinstance(info, dict) else None
    found = info.get("run") if info and isinstance(info.get("run"), str) else None
    if found and args.run and found != args.run:
        raise UserError(f"--out {out}: {out / RUN_FILE} holds run {found!r}, not {args.run!r} (drop --run, or "
                        f"give the directory of run {args.run!r})")
    args.run = args.run or found or DEFAULT_RUN
    if explicit_router(args):  # the router given; the run named is checked there (run_there)
        return out
    if not (info and isinstance(info.get("endpoint"), str) and info["endpoint"]):
        if args.out is not None:
            raise UserError(f"--out {out}: no swarm run's {RUN_FILE} with its router endpoint there (a directory "
                            f"`truav-swarm up --out` wrote); or give -e/--connect ENDPOINT and --run NAME")
        raise UserError(f"--run {args.run}: no such run: {out / RUN_FILE} does not exist (`truav-swarm up --run "
                        f"{args.run}` writes it); for a run with another --out pass --out DIR, or -e/--connect "
                        f"ENDPOINT with --run NAME")
    check_endpoint(f"{out / RUN_FILE}: endpoint", info["endpoint"])
    if (out / SUMMARY_FILE).is_file():  # written when a run ends; removed when one starts
        raise UserError(f"run {args.run!r} in {out} has ended ({out / SUMMARY_FILE} holds its summary): "
                        f"nothing of it is running")
    if not _pid_running(info.get("supervisor_pid")):
        raise UserError(f"run {args.run!r} in {out} has ended (its supervisor, PID {info['supervisor_pid']} "
                        f"in {out / RUN_FILE}, is not running)")
    if (out / runlock.LOCK_FILE).is_file() and runlock.holder(out) is None and not runlock.held_here(out):
        raise UserError(f"run {args.run!r} in {out} has ended (no process holds its lock "
                        f"{out / runlock.LOCK_FILE})")
    args.connect = [info["endpoint"]]
    check_tls_creds(args, f"{out / RUN_FILE}: endpoint")
    return out


def where(args) -> str:
    """The router a command reached, in words."""
    if args.connect:
        return ", ".join(args.connect)
    return f"the router of --creds {args.creds}" if getattr(args, "creds", None) else f"the router of -c {args.config}"


def run_there(bus, args, timeout: float) -> tuple[list[str], str | None]:
    """The liveliness tokens of ``args.run`` on ``bus``'s router, and, when there are none, the one-line
    reason: another run is what this router serves (never to be listed or acted on in its place), or
    nothing at all."""
    from truav.wire import keys
    tokens = sorted(bus.alive(keys.all_alive(args.run), timeout=timeout))
    if tokens:
        return tokens, None
    others = sorted({k.split("/")[1] for k in bus.alive("truav/*/alive/**", timeout=min(timeout, OTHER_RUNS_WAIT_S))
                     if k.count("/") >= 2})
    if others:
        return [], (f"no process of run {args.run!r} at {where(args)}: it serves run(s) "
                    f"{', '.join(repr(r) for r in others)}, not the one named (--run NAME or --out DIR of "
                    f"the run you mean)")
    return [], f"no process of run {args.run!r} alive at {where(args)}"


RUN_HELP = ("the run, by name: the swarm.json in its directory runs/swarm-NAME gives its router (default demo; "
            "with -e, -c or --creds: the run that must be there)")
OUT_HELP = ("the run, by the directory `truav-swarm up --out DIR` writes: its swarm.json gives the run's name and "
            "router (with --run, it must hold that run)")


def add_run_args(p, run_help: str = RUN_HELP, out_help: str = OUT_HELP) -> None:
    """--run NAME and --out DIR: how these commands name the run they act on (:func:`find_run`)."""
    from truav.cli.args import run_name
    p.add_argument("--run", type=run_name, default=None, metavar="NAME", help=run_help)
    p.add_argument("--out", metavar="DIR", help=out_help)

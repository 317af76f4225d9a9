"""`truav-swarm up --external IDS`: UAVs whose agent is not the project's but the user's.

`up` starts everything but those UAVs' agents, prints for each the command that flies it with
examples/outside_agent.py (endpoint and, under --secure, its credentials), waits up to --external-wait
for its liveliness token before tick 0, and reports on it from the world's accounting (an external
agent has no process and no statistics file of its own). Pure code: the checks, the texts and the
verdicts; the supervisor does the waiting (truav.swarm.swarm_watch) and the printing.

How it combines with the other flags of `up`:

* ``--scheme``: truav only (patrol and central agents are not meant to be swapped for another's).
* ``--agents-per-process K``: the project's UAVs keep their groups of K consecutive ids, with the
  external ones left out (a group left empty has no process); not with ``--batch-beacons`` (a
  process's batch key names a range of consecutive ids).
* ``--fault-plan``: a crash or freeze of an external UAV's agent is refused (it is not a process
  of the swarm); link faults apply to it as to any UAV.
* ``--lockstep``: the printed command has ``--lockstep``; the world and the project's agents wait for
  the external agent as for any live agent (``--lockstep-wait``).
* ``--secure``: the printed command has ``-c <out>/creds/uav-<i>.json5`` (the UAV's own identity and
  certificate, issued with everyone else's); the router lets it use only that UAV's keys.
* ``--wait-agents``: the world waits ``--wait-agents`` + ``--external-wait`` for all agents, so that
  the supervisor's bounded wait for the external ones, with its progress lines, decides.
"""

from __future__ import annotations

import shlex
from pathlib import Path

from truav.bus.acl import file_stem
from truav.errors import UserError  # a user mistake: one line, exit 2 (as truav/swarm/checks.py)
from truav.wire import keys

DEFAULT_EXTERNAL_WAIT_S = 300.0
"""How long `up` waits for an external UAV's liveliness token before tick 0: time to read the printed
command and start it in another terminal."""
PROGRESS_EVERY_S = 10.0
"""A "waiting for external uav/<i>" line this often while one is missing."""
EXAMPLE = Path(__file__).resolve().parent.parent.parent / "examples" / "outside_agent.py"


def check_external(ids: tuple[int, ...], n_uavs: int, args, plan) -> None:
    """--external with this swarm: its ids exist and nothing else given asks the impossible of them."""
    if not ids:
        return
    flag = f"--external {','.join(map(str, ids))}"
    outside = [i for i in ids if i >= n_uavs]
    if outside:
        raise UserError(f"{flag}: UAV id(s) {', '.join(map(str, outside))} outside [0, {n_uavs}) "
                         f"(--agents / scenario.n_uavs is {n_uavs})")
    if args.scheme != "truav":
        raise UserError(f"{flag}: only --scheme truav leaves a UAV to an outside agent (this is --scheme "
                         f"{args.scheme})")
    if args.batch_beacons:
        raise UserError(f"{flag}: --batch-beacons sends a process's beacons under its range of consecutive UAV "
                         f"ids; drop --batch-beacons")
    for f in (plan.faults if plan is not None else ()):
        if f.kind in ("crash", "freeze") and f.params.get("uav") in ids:
            raise UserError(f"{flag}: the fault plan {args.fault_plan} {'crashes' if f.kind == 'crash' else 'freezes'} "
                             f"uav {f.params['uav']}, whose agent is not a process of this swarm; drop that fault or "
                             f"that UAV from --external")


def agent_ids(n_uavs: int, external: tuple[int, ...]) -> list[int]:
    """The UAVs the project's agents fly."""
    return [i for i in range(n_uavs) if i not in external]


def _shown(path: Path) -> str:
    """A path as a command typed here would name it: relative when under this directory."""
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path.resolve())


def creds_file(out: Path, uav: int) -> Path:
    """A --secure run's client config for UAV ``uav`` (truav.bus.security.secure_setup issues it)."""
    return Path(out) / "creds" / f"{file_stem(keys.uav_identity(uav))}.json5"


def agent_command(uav: int, run: str, endpoint: str, *, lockstep: bool, creds: Path | None) -> list[str]:
    """The example agent's command line for UAV ``uav`` (examples/outside_agent.py's flags)."""
    link = ["-c", str(creds)] if creds is not None else ["-e", endpoint]
    return ["python", _shown(EXAMPLE), "--run", run, *(["--lockstep"] if lockstep else []), "--id", str(uav), *link]


def instructions(ids: tuple[int, ...], run: str, endpoint: str, out: Path, *, lockstep: bool, secure: bool,
                 wait_s: float) -> list[str]:
    """What `up` prints once its router is up: for each external UAV, how to fly it."""
    lines = []
    for i in ids:
        creds = creds_file(out, i) if secure else None
        lines.append(f"external uav/{i}: this swarm leaves UAV {i} to your agent; fly it with the example "
                     f"(from {Path.cwd()}):")
        lines.append("  command: " + shlex.join(agent_command(i, run, endpoint, lockstep=lockstep, creds=creds)))
        lines.append(f"  endpoint: {endpoint}" + ("" if creds is None else
                     f"; credentials: {_shown(creds)} (identity {keys.uav_identity(i)}: a zenoh config holding its "
                     f"certificate, key and the CA inline; plain zenoh loads it from any directory)"))
        lines.append(f"  tick 0 waits for its liveliness token {keys.alive_uav(run, i)} (at most --external-wait "
                     f"{wait_s:g} s){'; lock-step' if lockstep else ''}; protocol: docs/reference/protocol.md")
    return lines


def waiting_line(missing: list[int], waited_s: float, wait_s: float) -> str:
    who = ", ".join(f"uav/{i}" for i in missing)
    return f"waiting for external {who} (start it with the command above) ... {waited_s:.0f} s of {wait_s:g}"


def never_joined_text(missing: list[int], wait_s: float, run: str) -> str:
    who = ", ".join(f"uav/{i}" for i in missing)
    return (f"external {who} never joined: no liveliness token {keys.alive_uav(run, missing[0])}"
            f"{' (or of the others)' if len(missing) > 1 else ''} within --external-wait {wait_s:g} s; start it with "
            f"the command printed at the start (or give a longer --external-wait)")


def accounting(world: dict | None, uav: int) -> dict:
    """UAV ``uav``'s actions as the world counted them: world.json's ``per_uav`` entry when it has one
    (received, applied, late, stale, missed, rejected by reason), else what the swarm totals give for
    one sender (its rejected messages, by reason)."""
    world = world or {}
    for entry in world.get("per_uav") or []:
        if isinstance(entry, dict) and entry.get("uav") == uav:
            return dict(entry)
    sender = keys.uav_identity(uav)
    rejected = {reason: int(senders.get(sender, 0)) for reason, senders in (world.get("rejected") or {}).items()
                if isinstance(senders, dict) and senders.get(sender)}
    return {"uav": uav, "rejected": rejected}


def report(world: dict | None, uav: int, joined_s: float | None) -> dict:
    """summary.json's outcome.external entry for one external UAV."""
    return {"uav": uav, "joined_s": None if joined_s is None else round(joined_s, 2), **accounting(world, uav)}


def acting_ticks(world: dict | None) -> int:
    """Ticks that asked every UAV for an action (each episode's `done` tick asks none)."""
    world = world or {}
    return int(world.get("ticks", 0)) - len(world.get("episodes") or [])


def verdicts(entry: dict, world: dict | None, max_missed_share: float) -> tuple[list[str], list[str]]:
    """(failures, warnings) about one external UAV, from its report: it never joined; it missed more than
    --max-missed of its own actions (the swarm's share would hide one UAV in five); it sent rejected messages."""
    uav, failures, warnings = entry["uav"], [], []
    if entry.get("joined_s") is None:
        return failures, warnings  # the watch already failed the run, with the wait it gave
    expected = acting_ticks(world)
    if "missed" in entry and expected > 0:
        share = int(entry["missed"]) / expected
        if share > max_missed_share:
            failures.append(f"external uav/{uav} missed {int(entry['missed'])} of its {expected} actions "
                            f"({100 * share:.0f}%, more than --max-missed {max_missed_share:g})")
    rejected = entry.get("rejected") or {}
    if sum(rejected.values()):
        warnings.append(f"external uav/{uav}: the world refused {sum(rejected.values())} of its message(s) ("
                        + ", ".join(f"{r} {n}" for r, n in sorted(rejected.items())) + "; docs/reference/protocol.md)")
    return failures, warnings


def summary_line(entry: dict) -> str:
    """The summary's line for one external UAV."""
    uav = entry["uav"]
    if entry.get("joined_s") is None:
        return f"external uav/{uav}: never joined"
    head = f"external uav/{uav}: joined at {entry['joined_s']:.1f} s"
    if "applied" in entry:
        counts = "actions " + ", ".join(f"{k} {int(entry.get(k, 0))}" for k in ("received", "applied", "late", "stale",
                                                                                 "missed"))
    else:
        counts = "no per-UAV action counts in world.json"
    rejected = entry.get("rejected") or {}
    refused = ", ".join(f"{r} {n}" for r, n in sorted(rejected.items()) if n) or "none"
    return f"{head}; {counts}; messages rejected: {refused}"

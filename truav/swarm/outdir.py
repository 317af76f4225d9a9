"""A swarm run's output directory: fresh unless the user asks to resume.

`truav-swarm up` writes checkpoints, statistics, logs and pictures under
``--out``.  Agents resume from ``agent<i>.npz`` when it exists, so a second
run into the same directory would silently continue the first (and mix a
5-agent run's files with a 3-agent run's).  Hence:

* a non-empty ``--out`` is refused (as `truav train` does) unless
* ``--resume``: continue that run (its checkpoints), only with the same scenario; or
* ``--force``: delete the earlier run's files first (only files a swarm run
  writes: anything else in the directory is left alone).

Every run marks its directory with ``MARKER_FILE`` before it writes anything
else. A directory without it holds no run (a user's own ``summary.json`` or
``scenario.toml`` share a run's names by chance): the refusal says so.

A run that failed before its first tick (its marker, logs, a summary, no checkpoint and
no tick in the world's statistics) holds nothing to mix with: it is replaced without
--force, so the corrected command just runs. Without the marker, nothing is
replaced without --force.

Within one run a crashed agent that is restarted still resumes from its own
checkpoint: nothing is deleted after the start.

A directory in use by a live run (its lock held: :mod:`truav.swarm.runlock`) is neither replaced nor
continued, with or without --force or --resume: the refusal names the live run.
"""

from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path
from truav import jsonio
from truav.atomic import write_kept
from truav.swarm import runlock

PID_FILE = "pids.json"
SCENARIO_FILE = "scenario.toml"
RUN_FILE = "swarm.json"
"""Run name, router endpoint and supervisor PID of the run writing this directory
(`truav-swarm status/down --out DIR` read the endpoint from it)."""
SUMMARY_FILE = "summary.json"
LOG_DIR = "logs"
MARKER_FILE = "truav-run.json"
"""Written first by every run into its --out: the files in the directory matching its patterns are the run's."""

RESULT_PATTERNS = ("agent*.json", "agent*.json.tmp", "world.json", "world.json.tmp", "summary.json", "summary.png",
                   PID_FILE, RUN_FILE)
"""Results of one run: removed at every start (with --resume too), so a summary never shows an earlier run's."""
STATE_PATTERNS = ("agent*.npz", SCENARIO_FILE)
"""What a resumed run continues from."""
TEMP_PATTERNS = ("agent*.npz.tmp.npz", "agent*.*.tmp", "world.json.*.tmp", "summary.json.*.tmp", "pids.json.*.tmp",
                 "swarm.json.*.tmp", ".swarm.json.tmp")
"""Temporaries a process killed while writing leaves (named with its PID: see truav.atomic)."""
CHAOS_RESULTS = ("degradation.txt", "chaos.png", "chaos.json", "invariants.txt", "invariants.json")
"""The comparison of a chaos run's two runs: made again from them at every end (removed at every start)."""
CHAOS_SETTINGS_FILE = "chaos-settings.json"
"""The settings a chaos run's two runs were made with: --resume keeps a finished one only under the same."""
CHAOS_PATTERNS = CHAOS_RESULTS + ("nemesis-plan.toml", CHAOS_SETTINGS_FILE)
CHAOS_RUNS = ("baseline", "faulted")


class OutDirError(ValueError):
    """--out cannot be used as asked (a user mistake: one line, exit 2)."""


def entries(out: Path) -> list[Path]:
    """What ``out`` holds besides the run lock's file (a directory holding only that is empty)."""
    return [p for p in out.iterdir() if p.name != runlock.LOCK_FILE]


def _live_run_line(out: Path, holder: dict) -> str:
    run, pid = holder.get("run"), holder.get("pid")
    info = read_run_file(out) or {}
    endpoint = info.get("endpoint") if isinstance(info, dict) and info.get("supervisor_pid") == pid else None
    who = ", ".join(str(x) for x in (holder.get("command") or "a TRUAV command",
                                     f"PID {pid}" if isinstance(pid, int) else None,
                                     f"router {endpoint}" if isinstance(endpoint, str) else None) if x)
    stop = f"truav-swarm down --out {out}" if endpoint else "Ctrl-C where it runs"
    return (f"--out {out} is in use by the live run {run if isinstance(run, str) else '?'!r} ({who}): it is "
            f"neither replaced (--force) nor continued (--resume) while it runs; wait for its end, stop it "
            f"({stop}), or choose another --out")


def refuse_live(out: Path) -> None:
    """OutDirError naming the live run holding ``out`` (another process's), if one does."""
    holder = runlock.holder(out)
    if holder is not None:
        raise OutDirError(_live_run_line(out, holder))


@contextlib.contextmanager
def hold_run_dirs(dirs, *, run: str, command: str):
    """Hold the run locks of ``dirs`` (making them) for the block; OutDirError naming the live run when
    another process holds one (then none is held)."""
    taken: list[Path] = []
    try:
        for out in dirs:
            if out.exists() and not out.is_dir():
                raise OutDirError(f"--out {out} is a file, not a directory")
            holder = runlock.acquire(out, {"run": run, "command": command})
            if holder is not None:
                raise OutDirError(_live_run_line(out, holder))
            taken.append(out)
        yield
    finally:
        for out in reversed(taken):
            runlock.release(out)


def _remove(out: Path, patterns) -> None:
    for pattern in patterns:
        for path in out.glob(pattern):
            if path.is_file() or path.is_symlink():
                path.unlink()


def clear_swarm_files(out: Path) -> None:
    """Delete every file an earlier swarm run wrote into ``out`` (logs included)."""
    _remove(out, RESULT_PATTERNS + STATE_PATTERNS + TEMP_PATTERNS + (MARKER_FILE,))
    logs = out / LOG_DIR
    if logs.is_dir():
        _remove(logs, ("*.log",))
        if not any(logs.iterdir()):
            logs.rmdir()


def _never_ran(out: Path) -> bool:
    """True if ``out`` holds only what a run that failed before its first tick leaves: logs, a summary,
    statistics of processes stopped while waiting (the world's with 0 ticks), and no checkpoint."""
    if not (out / MARKER_FILE).is_file():
        return False
    for path in entries(out):
        if path.name == MARKER_FILE:
            continue
        if path.name == LOG_DIR and path.is_dir():
            if any(not (p.is_file() and p.suffix == ".log") for p in path.iterdir()):
                return False
        elif path.name.endswith(".npz") or not any(path.match(pattern) for pattern in RESULT_PATTERNS + (SCENARIO_FILE,)):
            return False
    try:
        return json.loads((out / "world.json").read_text()).get("ticks", 0) == 0
    except FileNotFoundError:
        return True
    except (OSError, ValueError, AttributeError):
        return False


def check_swarm_dir(out: Path, *, resume: bool, force: bool) -> None:
    """The refusals of :func:`prepare_swarm_dir` that need no scenario, without touching ``out`` (raises
    OutDirError): `up` says them before slow preparations (a SUMO trace) rather than after."""
    if resume and force:
        raise OutDirError("--resume and --force exclude each other (continue the run in --out, or replace it)")
    if out.exists() and not out.is_dir():
        raise OutDirError(f"--out {out} is a file, not a directory")
    refuse_live(out)
    if out.is_dir() and entries(out):
        legacy_resume = resume and any(out.glob("agent*.npz"))  # a run from before the marker: its checkpoints show it
        if not (out / MARKER_FILE).is_file() and not force and not legacy_resume:
            names = sorted(p.name for p in entries(out))
            shown = ", ".join(names[:4]) + (f" and {len(names) - 4} more" if len(names) > 4 else "")
            raise OutDirError(f"--out {out} holds files that are not a TRUAV swarm run's ({shown}); choose another "
                              f"--out, or --force to let the run replace the files of its own names in it")
        if not (force or resume or _never_ran(out)):
            raise OutDirError(f"--out {out} holds an earlier run; pass --resume to continue it, --force to replace "
                              f"it, or choose another --out")
    elif resume:
        raise OutDirError(f"--resume: {out} holds no run to resume")


def prepare_swarm_dir(out: Path, scenario_toml: str, *, resume: bool, force: bool) -> None:
    """Make ``out`` ready for a run: refuse, resume or clear as described above (raises OutDirError)."""
    check_swarm_dir(out, resume=resume, force=force)
    if out.is_dir() and entries(out):
        if force or (not resume and _never_ran(out)):
            clear_swarm_files(out)
        else:  # resume
            old = out / SCENARIO_FILE
            if old.is_file() and old.read_text() != scenario_toml:
                raise OutDirError(f"--resume: {out} holds a run with another scenario (agents, steps or --set "
                                  f"differ from {old}); use the same options, or --force to start afresh")
            _remove(out, RESULT_PATTERNS)
    out.mkdir(parents=True, exist_ok=True)
    (out / MARKER_FILE).write_text(jsonio.dumps({"writer": "truav-swarm up", "files": list(
        RESULT_PATTERNS + STATE_PATTERNS + TEMP_PATTERNS + (f"{LOG_DIR}/*.log",))}, indent=1))
    (out / LOG_DIR).mkdir(parents=True, exist_ok=True)
    (out / SCENARIO_FILE).write_text(scenario_toml)


def prepare_chaos_dir(out: Path, *, resume: bool, force: bool, check_only: bool = False) -> None:
    """The same rule for `truav-swarm chaos`, whose --out holds two swarm runs (``check_only``: its refusals,
    touching nothing)."""
    if resume and force:
        raise OutDirError("--resume and --force exclude each other (continue the run in --out, or replace it)")
    if out.exists() and not out.is_dir():
        raise OutDirError(f"--out {out} is a file, not a directory")
    for sub in (out, *(out / name for name in CHAOS_RUNS)):
        refuse_live(sub)
    if out.is_dir() and _holds_chaos_files(out) and not resume:
        if not force:
            raise OutDirError(f"--out {out} holds an earlier chaos run; pass --resume to continue it, --force to "
                              f"replace it, or choose another --out")
        if check_only:
            return
        _remove(out, CHAOS_PATTERNS + tuple(f"{name}.mcap" for name in CHAOS_RUNS))
        for name in CHAOS_RUNS:
            if (out / name).is_dir():
                clear_swarm_files(out / name)
    if not check_only:
        out.mkdir(parents=True, exist_ok=True)


def _holds_chaos_files(out: Path) -> bool:
    """Anything besides run locks and subrun directories holding nothing else."""
    return any(not (p.name in CHAOS_RUNS and p.is_dir() and not entries(p)) for p in entries(out))


def write_run_file(out: Path, info: dict) -> None:
    """Atomically: `status`, `down` and tests read it while the run starts (a half-written file read as empty)."""
    text = jsonio.dumps(info, indent=1).encode()
    write_kept(out / RUN_FILE, lambda f: f.write(text), lambda line: print(f"warning: {line}", flush=True))


def read_run_file(out: Path) -> dict | None:
    try:
        return json.loads((out / RUN_FILE).read_text())
    except (OSError, ValueError):
        return None


def check_record_path(record: str, force: bool) -> None:
    """Fail before anything starts when the recording cannot be written (a missing directory is made later)."""
    path = Path(record)
    if path.is_dir():
        raise OutDirError(f"--record {record} is a directory; give a file name such as {path / 'run.mcap'}")
    if path.exists() and not force:
        raise OutDirError(f"--record {record} exists; choose another file, or --force to overwrite it")
    for parent in path.absolute().parents:
        if parent.exists():
            if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
                raise OutDirError(f"--record {record}: {parent} is not a writable directory")
            return

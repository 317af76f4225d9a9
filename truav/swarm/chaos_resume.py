"""`truav-swarm chaos --resume`: which of the two swarm runs in --out are kept, and the one line a stopped
chaos run ends with.

A chaos run's --out holds two runs, ``baseline/`` and ``faulted/``. ``--resume`` keeps a run only if it
finished (truav.swarm.fault_sweep.is_finished: result ok, every episode asked for) with the same settings
(CHAOS_SETTINGS_FILE: seed, episodes, scenario, the plan's text, ...); any other run is made again from
scratch, its own files replaced as --force does, never continued from its checkpoints (a partial run would mix
into the comparison). The comparison (degradation table, figure, the invariants of the faulted run) is made
again from the two runs at every end, so a resumed chaos run ends with an uninterrupted one's comparison."""

from __future__ import annotations

import dataclasses
import json
import signal
from pathlib import Path

from truav import jsonio
from truav.config import Config, to_toml
from truav.stopping import exit_code_for, stopped_by
from truav.swarm.fault_sweep import STOP_CODES, finished_point
from truav.swarm.outdir import CHAOS_RESULTS, CHAOS_RUNS, CHAOS_SETTINGS_FILE, SUMMARY_FILE, OutDirError
from truav.swarm.swarm_options import SwarmOptions

INCIDENTAL = frozenset({"run", "out", "resume", "force", "quiet", "verbose", "plot", "listen", "foxglove_port",
                        "geo_origin", "plan", "fault_plan", "record", "record_modes", "wait_agents_s",
                        "router_timeout_s", "references"})
"""SwarmOptions fields that leave a run's numbers as they are: a resumed chaos run may change them."""


def settings(cfg: Config, opts: SwarmOptions, plan_path: str) -> dict[str, str]:
    """What a chaos run's two runs are made with: every option that can change their numbers, the scenario
    and the plan's text."""
    found = {f.name: repr(getattr(opts, f.name)) for f in dataclasses.fields(opts) if f.name not in INCIDENTAL}
    found["scenario"] = to_toml(cfg)
    found["plan"] = Path(plan_path).read_text()
    return found


def kept_runs(out: Path, now: dict[str, str], episodes: int) -> dict[str, str]:
    """With --resume: the summary.json text of each run in ``out`` to keep (finished, with the settings
    ``now``); OutDirError if ``out``'s runs were made with other settings. An earlier chaos run that recorded
    no settings keeps nothing."""
    try:
        before = json.loads((out / CHAOS_SETTINGS_FILE).read_text())
    except (OSError, ValueError):
        return {}
    if not isinstance(before, dict):
        return {}
    differ = [key for key in now if before.get(key) != now[key]]
    if differ:
        raise OutDirError(f"--resume: --out {out} holds a chaos run made with other settings ({', '.join(differ)} "
                          f"differ{'s' if len(differ) == 1 else ''} from {out / CHAOS_SETTINGS_FILE}); use the same "
                          f"options, or --force to start afresh")
    kept = {}
    for name in CHAOS_RUNS:
        text = finished_point(out / name / SUMMARY_FILE, episodes)
        if text is not None:
            kept[name] = text
    return kept


def start_fresh_comparison(out: Path, now: dict[str, str]) -> None:
    """Record the settings and remove the last comparison: it is made again from the two runs at the end."""
    (out / CHAOS_SETTINGS_FILE).write_text(jsonio.dumps(now, indent=1))
    for name in CHAOS_RESULTS:
        (out / name).unlink(missing_ok=True)


def finished(sub: Path, episodes: int) -> bool:
    return finished_point(sub / SUMMARY_FILE, episodes) is not None


class RunStopped(KeyboardInterrupt):
    """A swarm run of chaos ended because a signal stopped it; ``code``: the exit code that says which."""

    def __init__(self, code: int) -> None:
        super().__init__(f"stopped (exit {code})")
        self.code = code


def raise_if_stopped(rc: int, sub: Path) -> None:
    """RunStopped if the swarm run into ``sub`` that returned ``rc`` was stopped by a signal (a run stopped
    while it also failed, e.g. a lock-step wait cut short, is a stopped run: its summary says interrupted)."""
    if rc in STOP_CODES:
        raise RunStopped(rc)
    try:
        summary = json.loads((sub / SUMMARY_FILE).read_text())
    except (OSError, ValueError):
        return
    by = (summary.get("outcome") or {}).get("interrupted_by") if isinstance(summary, dict) else None
    if by:
        raise RunStopped(exit_code_for({"SIGTERM": signal.SIGTERM, "SIGHUP": signal.SIGHUP}.get(by, signal.SIGINT)))


def stop_code_of(exc: KeyboardInterrupt) -> int:
    """The exit code of a stopped chaos run: its swarm run's, or outside one that of the signal taken as
    Ctrl-C (SIGTERM, SIGHUP: truav.cli.args.run_main notes it)."""
    return exc.code if isinstance(exc, RunStopped) else exit_code_for(stopped_by() or signal.SIGINT)


@dataclasses.dataclass
class Progress:
    """Where a chaos run is (``stage``, e.g. "the faulted run") and which of its runs finished."""

    stage: str = "its preparation"
    finished: list[str] = dataclasses.field(default_factory=list)

    def stopped_line(self, resume: bool) -> str:
        """The one line of a chaos run stopped here."""
        done = self.finished
        kept = f" (the {' and '.join(done)} run{'s' if len(done) > 1 else ''} finished and kept)" if done else ""
        return (f"truav-swarm: interrupted in {self.stage}{kept}; run the same command "
                f"{'again' if resume else 'with --resume'} to continue")

"""The checker of `truav-swarm chaos`: what a user relies on, checked from a run's outputs.

Jepsen's checker after its nemesis: once a faulted run has ended, every
invariant below is checked from what the run left (summary.json, the logs,
/proc, the recording) and reported as a table, in the console and in
<out>/invariants.txt and .json; any violation makes `chaos` exit 1.

* the run ended ok (exit code 0, result ok);
* the recording passes `truav log check` (the CLI, run as a user would);
  when the router was killed, messages published while no router was up are
  lost on the wire: gaps that all fall within a router outage (from its death
  to :data:`RECONNECT_SLACK_S` after its restart), or a lost Ray node's outage
  (:func:`node_outages`), are reported, not violations;
* every agent restarted (by the plan or the supervisor) resumed from its last
  checkpoint (its log: the step it resumed at is the step of the last
  checkpoint it wrote before it died: the last logged, or the next one due by the
  run's cadence, summary.json's ``checkpoints``, whose log line the kill cut off);
* no more actions were missed in the last :func:`quiet_window_s` seconds, all
  after the plan's last fault ended, than a busy host misses without faults
  (:data:`HOST_LOAD_MISSED_SHARE` of the UAV-ticks; none when the number of UAVs is unknown);
* no process the supervisor started is left running;
* no process's memory grew by more than :data:`MAX_RSS_GROWTH_MB` (from its first
  sample, a settled process, to its largest);
* no traceback and no ERROR line in any log;
* every child's exit code is honest: 0, or SIGKILL from the plan's crash or a
  death the supervisor saw and restarted (or reported), and the supervisor's
  own exit code is the one its summary states.
"""

from __future__ import annotations

import json
import math
import re
import signal
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from agents.process.agent_process import checkpoint_due
from recorder.reader import iter_messages
from recorder.schemas import decode_envelope
from truav.faults import FaultPlan
from truav.swarm.children import truav_process
from truav import jsonio

MAX_RSS_GROWTH_MB = 100.0
"""Memory growth allowed per process over a run (the issue's 3-8 min soaks grew by at most 34 MB)."""
RECONNECT_SLACK_S = 10.0
"""After a router restart, how long its clients may take to reconnect (Zenoh retries with a backoff)."""
QUIET_WINDOW_S = 30.0
HOST_LOAD_MISSED_SHARE = 0.02
"""A busy host alone makes a real-time swarm miss a few actions, faults or not: up to this share of the
UAV-ticks is the host's, not a fault's (a no-fault baseline that misses more ran on a host too busy to
judge by; after the heal, a UAV that did not recover misses every tick, far above it)."""
LOG_CHECK_TIMEOUT_S = 600.0
PROCESS_GRACE_S = 5.0


@dataclass
class Invariant:
    name: str
    held: bool | None
    """True held, False violated, None not checked (never counted as held)."""
    detail: str

    @property
    def status(self) -> str:
        return "not checked" if self.held is None else "held" if self.held else "VIOLATED"


def not_checked(name: str, why: str) -> Invariant:
    """A row the run gave nothing to check (its status column says "not checked"; ``why`` is its detail)."""
    return Invariant(name, None, why)


def sound(rows: list[Invariant]) -> bool:
    """No invariant violated (what the exit code says; what was not checked is said by :func:`count_line`)."""
    return not any(r.held is False for r in rows)


def count_line(rows: list[Invariant]) -> str:
    """e.g. "6 of 6 checked held; 2 not checked: a, b": what was not checked is never counted as held."""
    checked = [r for r in rows if r.held is not None]
    held = sum(bool(r.held) for r in checked)
    skipped = [r.name for r in rows if r.held is None]
    line = f"{held} of {len(checked)} checked held" + ("" if sound(rows) else ": the run is NOT sound")
    return line + (f"; {len(skipped)} not checked: {', '.join(skipped)}" if skipped else "")


def heal_time(plan: FaultPlan) -> float:
    """When the plan's last fault has ended (s after tick 0); inf if one lasts to the end."""
    ends = [f.start + float(f.params.get("restart_after", 0.0)) if f.kind == "crash" else f.end for f in plan.faults]
    return max(ends, default=0.0)


def quiet_window_s(plan: FaultPlan, run_s: float) -> float:
    """The last seconds of a run of ``run_s`` checked for missed actions: at most 30 s, all after the heal
    (half the quiet tail, so the swarm has had the other half to recover); 0 when the plan never heals."""
    heal = heal_time(plan)
    return 0.0 if not math.isfinite(heal) or heal >= run_s else min(QUIET_WINDOW_S, (run_s - heal) / 2)


def check_run(out: Path, rc: int, plan: FaultPlan, rate_hz: float, record: str | None) -> list[Invariant]:
    """Every invariant of the run written to ``out`` (a `truav-swarm up --out`) that exited with ``rc``."""
    summary = _json(out / "summary.json") or {}
    outcome = summary.get("outcome") or {}
    procs = summary.get("processes") or []
    rows = [Invariant("the run ended ok", rc == 0 and outcome.get("result") == "ok",
                      f"exit code {rc}, result {outcome.get('result')}"
                      + (f": {'; '.join(outcome.get('failures') or [])}" if outcome.get("failures") else ""))]
    rows.append(_log_check(record, (summary.get("router_outages_wall_ns") or []) + node_outages(summary)))
    rows.append(_resumed(out, procs, summary))
    rows.append(_quiet_tail(summary, plan, rate_hz))
    rows.append(_left_behind(procs))
    rows.append(_memory(procs))
    rows.append(_log_lines(out / "logs"))
    rows.append(_exit_codes(procs, plan, outcome, rc))
    return rows


def table(rows: list[Invariant]) -> str:
    width = max(len(r.name) for r in rows)
    lines = [f"{'invariant':<{width}}  {'':11}  detail", "-" * (width + 40)]
    lines += [f"{r.name:<{width}}  {r.status:11}  {r.detail}" for r in rows]
    lines.append(count_line(rows))
    return "\n".join(lines)


def write(out: Path, rows: list[Invariant]) -> tuple[Path, Path]:
    txt, js = out / "invariants.txt", out / "invariants.json"
    txt.write_text(table(rows) + "\n")
    js.write_text(jsonio.dumps({"sound": sound(rows), "held": sum(r.held is True for r in rows),
                                "violated": sum(r.held is False for r in rows),
                                "not_checked": sum(r.held is None for r in rows),
                                "invariants": [{**asdict(r), "status": r.status} for r in rows]}, indent=1))
    return txt, js


# -- the invariants -------------------------------------------------------------------
def _log_check(record: str | None, outages: list[list[int]]) -> Invariant:
    name = "the recording passes truav log check"
    if not record:
        return not_checked(name, "nothing recorded (no --record)")
    try:
        done = subprocess.run([sys.executable, "-m", "truav.cli", "log", "check", record], capture_output=True,
                              text=True, timeout=LOG_CHECK_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        return Invariant(name, False, f"`truav log check {record}` took more than {LOG_CHECK_TIMEOUT_S:.0f} s")
    if done.returncode == 0:
        return Invariant(name, True, f"`truav log check {record}`: exit 0")
    problem = (done.stderr.strip().splitlines() or ["(no message)"])[-1]
    # "truav log check: FILE: p1; p2": with the router killed, losses are expected; anything else is not
    if outages and only_losses(problem, record):
        gaps, unexplained = _gaps_outside(record, outages)
        if not unexplained:
            return Invariant(name, True, f"{_outside_parentheses(problem.split(f'{record}: ', 1)[-1])}, all in "
                                         f"{gaps} gap(s) while the router "
                                         f"or a Ray node was down ({len(outages)} outage(s)); nothing else")
        return Invariant(name, False, f"{problem}; {len(unexplained)} gap(s) outside any router or node outage, e.g. "
                                      f"{unexplained[0]}")
    return Invariant(name, False, f"exit {done.returncode}: {problem}")


def node_outages(summary: dict) -> list[list[int]]:
    """The outage of each Ray node lost mid-run (summary.json's ``node_losses``, truav.swarm.ray_recovery), as
    (lost, back) wall-clock ns: its loss to the last of its agents acting again (the run's end if one never did)."""
    end = int(summary.get("t0_wall_ns") or 0) + int(float(summary.get("elapsed_s") or 0) * 1e9)
    return [[n["lost_wall_ns"], n["lost_wall_ns"] + int(n["outage_s"] * 1e9) if n.get("outage_s") is not None
             else max(end, n["lost_wall_ns"])] for n in summary.get("node_losses") or []]


def only_losses(problem: str, record: str) -> bool:
    """Whether `truav log check`'s error line ("truav log check: FILE: p1 (details); p2") names only
    messages missing (lost on the wire), nothing else (duplicates, reordering, damage, an unfinished file)."""
    parts = _outside_parentheses(problem.split(f"{record}: ", 1)[-1]).split("; ")
    return all(re.search(r"\bmissing\b", p) for p in parts if p.strip())


def _outside_parentheses(text: str) -> str:
    """``text`` without its (possibly nested) parenthesised details, which may hold "; " themselves."""
    out, depth = [], 0
    for n, c in enumerate(text):
        depth += c == "(" and (depth > 0 or n == 0 or text[n - 1] == " ")  # "message(s)" is not a detail
        if depth == 0:
            out.append(c)
        depth -= c == ")" and depth > 0
    return "".join(out).replace(" ;", ";").strip()


def _gaps_outside(record: str, outages: list[tuple[int, int]]) -> tuple[int, list[str]]:
    """The seq gaps of every sender's stream, and those not within a router outage (plus reconnect slack)."""
    windows = [(a - int(1e9), b + int(RECONNECT_SLACK_S * 1e9)) for a, b in outages]
    last: dict[tuple[str, str], tuple[int, int]] = {}  # (src, kind) -> (seq, log_ns)
    gaps, outside = 0, []
    for key, payload, log_ns, _ in iter_messages(record):
        env = decode_envelope(payload)
        if env is None:
            continue
        stream = (env.src, env.kind)
        prev = last.get(stream)
        last[stream] = (env.seq, log_ns)
        if prev is None or env.seq <= prev[0]:  # a new incarnation numbers from 0 again (or a reordering)
            continue
        if env.seq > prev[0] + 1:
            gaps += 1
            if not any(lo <= log_ns and prev[1] <= hi for lo, hi in windows):
                outside.append(f"{env.src} {env.kind} seq {prev[0] + 1}-{env.seq - 1}")
    return gaps, outside


_RESUMED = re.compile(r"uav (\d+)(?: \(agent [^)]*\))? resumed from checkpoint .* at step (\d+)")  # --agent: its name
_CHECKPOINT = re.compile(r"uav (\d+): checkpoint at step (\d+)")
_JOINED = re.compile(r"uav (\d+) joined run")


def _next_checkpoint(step: int | None, uav: int, cadence: tuple[int, int] | None, prev: int | None) -> int | None:
    """The checkpoint UAV ``uav`` writes next after the one of ``step`` (None: none yet, step 0): with the run's
    ``cadence`` (steps between checkpoints, UAVs: :func:`checkpoint_due`'s), exactly; without it (an older run's
    summary), one cadence on, the distance of the last two logged (``prev``, ``step``); None if unknown."""
    if cadence is not None:
        every, n_uavs = cadence
        base = step or 0
        return next(s for s in range(base + 1, base + every + 1) if checkpoint_due(s, uav, n_uavs, every))
    return step + (step - prev) if step is not None and prev is not None else None


def _cadence(summary: dict) -> tuple[int, int] | None:
    ck = summary.get("checkpoints") or {}
    every, uavs = ck.get("every_steps"), ck.get("uavs")
    return (every, uavs) if isinstance(every, int) and isinstance(uavs, int) and every > 0 and uavs > 0 else None


def _resumed(out: Path, procs: list[dict], summary: dict | None = None) -> Invariant:
    """From each restarted agent's log (its processes append to one file): every "resumed from checkpoint
    at step N" names the checkpoint in force when it died (the last logged one or the last resumed from, or the
    next one due, whose log line the kill cut off: the line follows the file's atomic replace), and every later
    join that had a checkpoint to resume from did.  Each UAV of the log is judged from its own lines; which
    checkpoint is due next comes from summary.json's ``checkpoints`` (read from ``out`` unless given).  (A process
    killed while still starting may leave only its resume line.)"""
    name = "every restarted agent resumed from its checkpoint"
    cadence = _cadence(summary if summary is not None else _json(out / "summary.json") or {})
    restarted = sorted({p["name"] for p in procs if p["name"].startswith("agent")
                        and sum(q["name"] == p["name"] for q in procs) > 1})
    bad, steps = [], []
    for agent in restarted:
        try:
            text = (out / "logs" / f"{agent}.log").read_text(errors="replace")
        except OSError:
            bad.append(f"{agent}: no log")
            continue
        last_ck, prev_ck, resumed, joins = {}, {}, {}, {}  # per UAV: the checkpoint in force, the one before it
        for line in text.splitlines():
            if m := _CHECKPOINT.search(line):
                uav = int(m.group(1))
                prev_ck[uav], last_ck[uav] = last_ck.get(uav), int(m.group(2))
            elif m := _RESUMED.search(line):
                uav, step = int(m.group(1)), int(m.group(2))
                last = last_ck.get(uav)
                if step not in (last, _next_checkpoint(last, uav, cadence, prev_ck.get(uav))):
                    bad.append(f"{agent}: resumed at step {step}, its last checkpoint was "
                               f"{'none' if last is None else f'at step {last}'}")
                if step != last:  # the checkpoint it loaded is the one in force from now on
                    prev_ck[uav], last_ck[uav] = last, step
                steps.append(step)
                resumed[uav] = True
            elif m := _JOINED.search(line):
                uav = int(m.group(1))
                n = joins.get(uav, 0)
                if n and not resumed.get(uav) and last_ck.get(uav) is not None:
                    bad.append(f"{agent} restart {n}: started fresh, its checkpoint at step {last_ck[uav]} unused")
                elif n and not resumed.get(uav):
                    steps.append(None)
                joins[uav], resumed[uav] = n + 1, False
    if bad:
        return Invariant(name, False, "; ".join(bad[:3]))
    if not restarted:
        return Invariant(name, True, "no agent was restarted")
    n = sum(p["name"] in restarted for p in procs) - len(restarted)
    return Invariant(name, True, f"{n} restart(s) of {len(restarted)} agent(s); {len(steps)} resumed, each from its "
                                 f"last checkpoint (steps {', '.join('fresh' if s is None else str(s) for s in steps[:8])}"
                                 f"{', ...' if len(steps) > 8 else ''})")


def _quiet_tail(summary: dict, plan: FaultPlan, rate_hz: float) -> Invariant:
    hovering = (summary.get("timeline") or {}).get("hovering") or []
    if not hovering:
        return Invariant("no missed action after the heal", False, "no step metrics heard")
    end_tick = hovering[-1][0]
    window = quiet_window_s(plan, end_tick / rate_hz)
    name = f"no missed action in the last {window:.0f} s (after the heal)"
    if window <= 0 and not math.isfinite(heal_time(plan)):  # a plan of one's own may fault to the end
        return not_checked("no missed action after the heal", "the plan's faults last to the end of the run "
                                                                 "(no quiet tail)")
    if window <= 0:  # a --plan run shorter than its plan (a nemesis run lasts past its heal by construction;
        # ending early fails "the run ended ok"): nothing after the heal to check
        return not_checked("no missed action after the heal", f"the run's last tick ({end_tick / rate_hz:.1f} s) came "
                                                                 f"before the plan's heal ({heal_time(plan):.1f} s)")
    ticks = [(t, h) for t, h in hovering if t / rate_hz >= end_tick / rate_hz - window]
    missed = sum(h for _, h in ticks)
    n_uavs = len((summary.get("world") or {}).get("per_uav") or [])
    allowed = math.floor(HOST_LOAD_MISSED_SHARE * n_uavs * len(ticks))
    return Invariant(name, missed <= allowed,
                     f"{missed:g} UAV-tick(s) without an action in ticks {ticks[0][0]}-{end_tick}, at most {allowed} "
                     f"allowed ({100 * HOST_LOAD_MISSED_SHARE:g}% of {n_uavs} UAVs x {len(ticks)} ticks: a busy host's)"
                     f" (the last fault ended at {heal_time(plan):.1f} s)")


def _running(pid: int) -> bool:
    """A process of this run still running (not a zombie, and still a TRUAV command: PIDs get reused)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != "Z" and truav_process(pid)


def _left_behind(procs: list[dict]) -> Invariant:
    deadline = time.monotonic() + PROCESS_GRACE_S
    while any(_running(p["pid"]) for p in procs) and time.monotonic() < deadline:
        time.sleep(0.2)
    left = [f"{p['name']} (pid {p['pid']})" for p in procs if _running(p["pid"])]
    return Invariant("no process left behind", not left and bool(procs),
                     f"still running: {', '.join(left)}" if left else f"all {len(procs)} process(es) started have exited")


def _memory(procs: list[dict]) -> Invariant:
    growth = [(p["rss_max_mb"] - p["rss_first_mb"], p) for p in procs if p.get("rss_first_mb") is not None]
    name = f"memory growth at most {MAX_RSS_GROWTH_MB:g} MB per process"
    if not growth:
        return not_checked(name, "no process lived long enough to be sampled")
    worst, p = max(growth, key=lambda g: g[0])
    return Invariant(name, worst <= MAX_RSS_GROWTH_MB,
                     f"worst: {p['name']} (pid {p['pid']}) {p['rss_first_mb']:.0f} -> {p['rss_max_mb']:.0f} MB "
                     f"({worst:+.1f} MB); {len(growth)} process(es) sampled")


def _log_lines(logs: Path) -> Invariant:
    hits = []
    for path in sorted(logs.glob("*.log")):
        for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            if "Traceback" in line or " ERROR " in line:
                hits.append(f"{path.name}:{n}: {line.strip()[:120]}")
    return Invariant("no traceback or ERROR line in the logs", not hits,
                     f"{len(hits)} line(s), first {hits[0]}" if hits else f"{len(list(logs.glob('*.log')))} log(s) read")


def _exit_codes(procs: list[dict], plan: FaultPlan, outcome: dict, rc: int) -> Invariant:
    planned: dict[str, int] = {}
    for f in plan.faults:
        if f.kind == "crash":
            who = f.params.get("target", f.params.get("uav"))
            name = who if isinstance(who, str) else f"agent{who}"
            planned[name] = planned.get(name, 0) + 1
    restarted = {r["old_pid"] for r in outcome.get("restarts") or []}
    superseded = {s["pid"] for s in outcome.get("superseded") or []}  # e.g. a router that lost its port at once
    healed = restarted | superseded
    bad = []
    for p in procs:
        code = p["exit_code"]
        if code == 0 or p["pid"] in healed:
            continue
        if code == -signal.SIGKILL and planned.get(p["name"], 0) > 0:
            planned[p["name"]] -= 1
            continue
        bad.append(f"{p['name']} (pid {p['pid']}): {'still running' if code is None else f'exit {code}'}")
    if outcome.get("exit_code") != rc or (rc == 0) != (outcome.get("result") == "ok"):
        bad.append(f"the supervisor exited {rc}, its summary says {outcome.get('exit_code')} ({outcome.get('result')})")
    return Invariant("honest exit codes", not bad,
                     "; ".join(bad[:3]) if bad else f"{len(procs)} process(es): 0, or killed by the plan "
                                                   f"({sum(1 for p in procs if p['exit_code'] == -signal.SIGKILL)}),"
                                                   f" or restarted by the supervisor ({len(restarted)})"
                                                   + (f", or superseded at its start ({len(superseded)})"
                                                      if superseded else ""))


def _json(path: Path):
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None

"""Issue 54: a run directory in use by a live swarm is never replaced nor continued by another command.

The run's supervisor holds a lock (flock) on ``<out>/.truav-run.lock`` for the whole run; `up` (with or
without --force or --resume) and `chaos` into a directory whose lock is held say so in one line naming
the live run and exit 2, touching nothing. A SIGKILLed holder's lock is released by the kernel: it does
not block the next run.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tests.support.swarm_up import SMALL, up  # noqa: F401 - the fixture
from truav.cli.swarm import main as swarm_main
from truav.swarm.outdir import OutDirError, check_swarm_dir, prepare_chaos_dir

TINY = ["--scheme", "truav", "--agents", "2", "--steps", "5", "--episodes", "1", *SMALL]

HOLDER = """
import sys, time
from pathlib import Path
from truav.swarm.outdir import hold_run_dirs
with hold_run_dirs([Path(p) for p in sys.argv[2:]], run=sys.argv[1], command="truav-swarm chaos"):
    print("held", flush=True)
    time.sleep(600)
"""


def _hold(run: str, *dirs: Path) -> subprocess.Popen:
    """A process holding the run locks of ``dirs`` (as a live chaos run does) until it is killed."""
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, run, *map(str, dirs)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


def _one_line(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    return err.strip()


def test_force_on_a_live_swarm_is_refused_and_its_files_kept(up, tmp_path, capsys) -> None:  # noqa: F811
    first = up("live", "--agents", "2", "--steps", "20", "--episodes", "500", "--max-missed", "1")
    endpoint = first.wait_ticking()
    out = first.out
    pid, world_pid = first.proc.pid, first.pids["world"]
    # The real entry point, to its end: a second supervisor refused before it starts anything.
    second = subprocess.run([sys.executable, "-m", "truav.cli.swarm", "up", "--run", "other", "--out", str(out),
                             "--force", "--quiet", "--no-plot", *TINY], capture_output=True, text=True, timeout=120)
    lines = second.stderr.strip().splitlines()
    assert second.returncode == 2 and len(lines) == 1, second.stderr + second.stdout
    assert "live run 'live'" in lines[0] and f"PID {pid}" in lines[0] and endpoint in lines[0], lines[0]
    assert "--force" in lines[0], lines[0]
    for extra in (["--force"], ["--resume"], []):  # in process: the same refusal, whatever the flag
        assert swarm_main(["up", "--run", "live", "--out", str(out), "--quiet", "--no-plot", *TINY, *extra]) == 2
        assert "live run 'live'" in _one_line(capsys)
    assert json.loads((out / "swarm.json").read_text())["supervisor_pid"] == pid  # not rewritten
    assert first.proc.poll() is None  # still running, its files in place
    assert swarm_main(["down", "--out", str(out), "--wait", "60"]) == 0
    assert first.wait(timeout=120) == 130, first.output()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outcome"]["ended_by"].endswith("`truav-swarm down`)"), summary["outcome"]
    assert json.loads((out / "pids.json").read_text())["world"] == world_pid  # its own processes only
    # Once it has ended, --force replaces it.
    capsys.readouterr()
    assert swarm_main(["up", "--run", "next", "--out", str(out), "--force", "--lockstep", "--quiet", "--no-plot",
                       *TINY]) == 0, capsys.readouterr()
    assert json.loads((out / "swarm.json").read_text())["run"] == "next"


def test_a_killed_holder_leaves_no_lock_behind(tmp_path) -> None:
    out = tmp_path / "run"
    holder = _hold("gone", out)
    with pytest.raises(OutDirError, match=rf"live run 'gone' \(truav-swarm chaos, PID {holder.pid}\)"):
        check_swarm_dir(out, resume=False, force=True)
    holder.send_signal(signal.SIGKILL)
    holder.wait(timeout=30)
    check_swarm_dir(out, resume=False, force=True)  # the kernel released it
    holder = _hold("again", out)  # and the next one takes it
    holder.kill()
    holder.wait(timeout=30)


def test_chaos_refuses_a_live_run_and_holds_its_subruns(tmp_path, capsys, monkeypatch) -> None:
    out = tmp_path / "chaos"
    holder = _hold("busy", out, out / "baseline", out / "faulted")
    try:
        plan = tmp_path / "plan.toml"
        plan.write_text('[[fault]]\nkind = "loss"\nstart = 1.0\nduration = 1.0\nprobability = 0.5\n')
        for extra in (["--force"], ["--resume"], []):
            assert swarm_main(["chaos", "--plan", str(plan), "--out", str(out), *TINY, *extra]) == 2
            assert "live run 'busy'" in _one_line(capsys)
        assert swarm_main(["up", "--out", str(out / "faulted"), "--force", *TINY]) == 2  # one of its subruns
        assert "live run 'busy'" in _one_line(capsys)
    finally:
        holder.kill()
        holder.wait(timeout=30)
    # A chaos run holds its directory and both subruns while it runs (here: while its first "run" runs).
    import truav.swarm.chaos as chaos
    seen = []

    def probe(cfg, opts) -> int:
        code = ("import sys; from pathlib import Path; from truav.swarm.outdir import check_swarm_dir\n"
                "for p in sys.argv[1:]:\n"
                "    try: check_swarm_dir(Path(p), resume=False, force=True); print('free')\n"
                "    except ValueError as exc: print(exc)\n")
        seen.extend(subprocess.run([sys.executable, "-c", code, str(out), str(out / "baseline"), str(out / "faulted")],
                                   capture_output=True, text=True, timeout=120).stdout.splitlines())
        return 1
    monkeypatch.setattr(chaos, "run_swarm", probe)
    assert swarm_main(["chaos", "--plan", str(plan), "--out", str(out), "--force", *TINY]) == 1
    assert len(seen) == 3 and all("live run 'demo'" in line for line in seen), seen
    prepare_chaos_dir(out, resume=False, force=True)  # released at its end


def test_a_fresh_dir_holding_only_a_released_lock_counts_as_empty(tmp_path) -> None:
    out = tmp_path / "run"
    holder = _hold("brief", out)
    holder.kill()
    holder.wait(timeout=30)
    assert [p.name for p in out.iterdir()] == [".truav-run.lock"]
    check_swarm_dir(out, resume=False, force=False)  # not "holds files that are not a run's"
    with pytest.raises(OutDirError, match="holds no run to resume"):
        check_swarm_dir(out, resume=True, force=False)


def test_a_killed_supervisor_does_not_block_the_next_run(up, tmp_path, capsys) -> None:  # noqa: F811
    """The lock is the supervisor's alone (its processes do not inherit it): SIGKILLed, its directory is free
    at once, while its orphans are still stopping; the next run with --force runs."""
    first = up("killed", "--agents", "2", "--steps", "20", "--episodes", "500", "--max-missed", "1")
    first.wait_ticking()
    first.proc.send_signal(signal.SIGKILL)
    first.proc.wait(timeout=30)
    check_swarm_dir(first.out, resume=False, force=True)  # not "in use by the live run"
    assert first.left_running(grace=60) == []  # its children notice and stop by themselves
    assert swarm_main(["up", "--run", "after", "--out", str(first.out), "--force", "--lockstep", "--quiet",
                       "--no-plot", *TINY]) == 0, capsys.readouterr()

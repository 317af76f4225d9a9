"""`truav train` interrupted by SIGINT keeps what it finished and `--resume` continues it exactly:
its metrics.csv and qtables.npz equal, byte for byte, those of a run never interrupted."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

import truav.cli.main
from truav.cli.main import main as truav_main

ARGS = ["--seeds", "2", "--episodes", "30", "--quiet", "--set", "scenario.n_vehicles=60",
        "--set", "scenario.steps_per_episode=10", "--set", "roads.warmup_steps=10"]


@pytest.fixture(autouse=True)
def _sigint_raises():
    """Ctrl-C as in a terminal, however pytest was started: a shell starts background jobs (`cmd &`
    in a script, nohup) with SIGINT ignored, and `truav train` then rightly leaves it ignored."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


class _SigintAfter:
    """A progress bar that sends this process SIGINT (Ctrl-C) once ``n`` env-episodes have finished."""

    def __init__(self, n: int) -> None:
        self.n, self.seen, self.sent = n, 0, False

    def __call__(self, total, desc, quiet, initial=0):
        return self

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def update(self, n):
        self.seen += n
        if self.seen >= self.n and not self.sent:
            self.sent = True
            os.kill(os.getpid(), signal.SIGINT)

    def set_postfix_str(self, *a, **k):
        pass


@pytest.mark.parametrize("workers", [1, 2])
def test_interrupted_then_resumed_training_equals_an_uninterrupted_one(tmp_path, monkeypatch, capsys, workers):
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    assert truav_main(["train", *ARGS, "--workers", str(workers), "--out", str(whole)]) == 0
    with monkeypatch.context() as m:
        m.setattr(truav.cli.main, "progress_bar", _SigintAfter(6))
        assert truav_main(["train", *ARGS, "--workers", str(workers), "--out", str(cut)]) == 130
    err = capsys.readouterr().err
    assert "interrupted:" in err and "--resume" in err, err
    assert (cut / "metrics.csv").is_file() and not (cut / "qtables.npz").exists()  # what it finished
    # The same command is refused with a pointer to --resume, not silently restarted.
    assert truav_main(["train", *ARGS, "--workers", str(workers), "--out", str(cut)]) == 2
    assert "--resume" in capsys.readouterr().err
    bar = _SigintAfter(10 ** 9)  # never fires: records where the resumed run's bar starts
    starts = []
    with monkeypatch.context() as m:
        m.setattr(truav.cli.main, "progress_bar", lambda total, desc, quiet, initial=0: starts.append(initial) or bar)
        assert truav_main(["train", *ARGS, "--workers", str(workers), "--out", str(cut), "--resume"]) == 0
    resumed_from = starts[0]  # env-episodes the checkpoints hold: the bar goes on from there, not from 0
    assert len(starts) == 1 and 0 < resumed_from < 2 * 30 and bar.seen == 2 * 30 - resumed_from
    out = capsys.readouterr().out
    assert f"over the {2 * 30 - resumed_from:,} env-episodes after the resume" in out, out
    for name in ("metrics.csv", "qtables.npz"):
        assert (cut / name).read_bytes() == (whole / name).read_bytes(), name
    assert not (cut / "resume").exists()  # finished: nothing left to resume


def test_resume_with_another_config_or_scheme_is_refused(tmp_path, monkeypatch, capsys):
    cut = tmp_path / "cut"
    with monkeypatch.context() as m:
        m.setattr(truav.cli.main, "progress_bar", _SigintAfter(2))
        assert truav_main(["train", *ARGS, "--workers", "1", "--out", str(cut)]) == 130
    capsys.readouterr()
    for extra, names in ((["--set", "scenario.n_vehicles=61"], "another config"), (["--seeds", "3"], "seeds"),
                         (["--scheme", "central"], "--scheme central cannot continue exactly"),
                         (["--force"], "--resume and --force")):
        argv = ["train", *ARGS, *extra, "--workers", "1", "--out", str(cut), "--resume"]
        assert truav_main(argv) == 2, extra
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and names in err[0], (extra, err)
    assert truav_main(["train", *ARGS, "--out", str(tmp_path / "none"), "--resume"]) == 2
    assert "holds no interrupted training" in capsys.readouterr().err


def test_a_damaged_checkpoint_is_one_line_before_anything_runs(tmp_path: Path) -> None:
    """A truncated chunk checkpoint is refused by --resume in one line (exit 2), not a worker's traceback."""
    from truav.analysis.runio import RESUME_DIR, write_resume_info
    out = tmp_path / "run"
    args = ["train", *ARGS, "--out", str(out)]
    assert subprocess.run([sys.executable, "-m", "truav.cli", *args], capture_output=True).returncode == 0
    write_resume_info(out, {"scheme": "truav", "seeds": [0, 1], "chunks": [[0, 1]]})
    (out / RESUME_DIR / "chunk0.pkl").write_bytes(b"\x80\x05garbage")
    proc = subprocess.run([sys.executable, "-m", "truav.cli", *args, "--resume"], capture_output=True, text=True)
    assert proc.returncode == 2, proc.stderr
    assert "chunk0.pkl is damaged" in proc.stderr and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr

"""Hard faults a swarm run meets on a real machine (issue 43): files in the way of --out, a second agent
for a live UAV, a stalled world, a full disk.

Real `truav-swarm up` runs (a small city, loopback) where a process is needed; every process is tracked
by PID and none may outlive its test.
"""

from __future__ import annotations

from pathlib import Path

from tests.support.swarm_up import SMALL
from truav.swarm import cli as swarm_cli
from truav.swarm.children import free_loopback_endpoint
from truav.swarm.outdir import MARKER_FILE


def _up_argv(out: Path, *extra: str) -> list[str]:
    return ["up", "--run", "hf", "--agents", "2", "--steps", "10", "--episodes", "1", "--lockstep", *SMALL,
            "--out", str(out), "-l", free_loopback_endpoint(), "--quiet", "--no-plot", *extra]


# -- nothing outside the run is touched --------------------------------------------------------
def test_users_own_files_in_out_are_refused_and_force_removes_only_what_a_run_writes(tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    mine = {"summary.json": '{"my": "results"}', "scenario.toml": "# my own scenario\n", "notes.txt": "mine"}
    for name, text in mine.items():
        (out / name).write_text(text)
    assert swarm_cli.main(_up_argv(out)) == 2  # no earlier run's marker: refused before anything starts
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "not a TRUAV swarm run's" in err and "--force" in err and str(out) in err
    assert {p.name for p in out.iterdir()} == set(mine)
    assert all((out / name).read_text() == text for name, text in mine.items())

    assert swarm_cli.main(_up_argv(out, "--force")) == 0
    assert (out / "notes.txt").read_text() == "mine"  # not a run's name: left alone
    assert (out / MARKER_FILE).is_file() and (out / "agent0.npz").is_file()
    capsys.readouterr()
    assert swarm_cli.main(_up_argv(out)) == 2  # now an earlier run: the usual refusal
    assert "holds an earlier run" in capsys.readouterr().err

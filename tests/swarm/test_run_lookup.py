"""Issue 54: `status`, `down`, `faults` and `replay-ctl` find a run by its directory (--out) or its name
(--run, its directory runs/swarm-<run>), never by a default port; one that reaches another run than the
one named (with -e ENDPOINT) says so in one line and stops, non-zero, without acting on it."""

from __future__ import annotations

import json

from tests.support.swarm_up import up  # noqa: F401 - the fixture
from truav.cli.swarm import main as swarm_main


def _one_line(capsys) -> tuple[str, str]:
    out, err = capsys.readouterr()
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, (out, err)
    return out, err.strip()


def test_commands_reach_only_the_run_they_name(up, tmp_path, capsys, monkeypatch) -> None:  # noqa: F811
    a = up("alpha", "--agents", "2", "--steps", "20", "--episodes", "500", "--max-missed", "1")
    endpoint = a.wait_ticking()
    monkeypatch.chdir(tmp_path)  # no runs/ here: the default run's directory does not exist
    empty = tmp_path / "empty.toml"
    empty.write_text("")

    # by directory: the run's own endpoint, its own tokens
    assert swarm_main(["status", "--out", str(a.out)]) == 0
    listed = capsys.readouterr().out
    assert "truav/alpha/alive/uav/0" in listed and "truav/alpha/alive/world" in listed, listed

    # nothing named: the default run's directory, never the default port
    for argv in (["status"], ["status", "--run", "beta"], ["down", "--run", "beta"], ["faults", "--plan", str(empty)],
                 ["replay-ctl", "--run", "beta", "status"]):
        assert swarm_main(argv) == 2, argv
        out, err = _one_line(capsys)
        assert "runs/swarm-" in err and "alpha" not in out, (argv, err)

    # a directory and another name: refused before connecting
    assert swarm_main(["status", "--out", str(a.out), "--run", "beta"]) == 2
    assert "holds run 'alpha', not 'beta'" in _one_line(capsys)[1]

    # an explicit endpoint serving another run: said, non-zero, nothing listed, sent or stopped
    for argv in (["status", "--run", "beta"], ["status"], ["down", "--run", "beta", "--wait", "1"],
                 ["faults", "--run", "beta", "--plan", str(empty)]):
        assert swarm_main([*argv, "-e", endpoint]) == 1, argv
        out, err = _one_line(capsys)
        assert "alive/uav" not in out and "sent" not in out, (argv, out)
        assert "alpha" in err and endpoint in err, (argv, err)

    # the run it names, by name: acts
    assert swarm_main(["faults", "--out", str(a.out), "--plan", str(empty)]) == 0
    assert "run alpha" in capsys.readouterr().out
    assert a.proc.poll() is None, a.output()  # nothing above stopped it
    assert swarm_main(["down", "--run", "alpha", "-e", endpoint, "--out", str(a.out), "--wait", "60"]) == 0
    assert a.wait(timeout=120) == 130, a.output()
    assert json.loads((a.out / "summary.json").read_text())["outcome"]["ended_by"].endswith("`truav-swarm down`)")


def test_record_ctl_finds_its_run_by_name_or_directory_too(tmp_path, capsys, monkeypatch) -> None:
    from truav.cli.main import main as truav_main
    monkeypatch.chdir(tmp_path)
    assert truav_main(["log", "record-ctl", "pause", "--run", "beta", "--wait", "1"]) == 2
    _, err = _one_line(capsys)
    assert "runs/swarm-beta/swarm.json" in err, err
    assert truav_main(["log", "record-ctl", "pause", "--out", str(tmp_path), "--wait", "1"]) == 2
    assert f"--out {tmp_path}" in _one_line(capsys)[1]

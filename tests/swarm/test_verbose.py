"""`-v`: every process of a swarm logs what it received, decided and sent, at a readable rate (at most
a line a second per process and call site); without -v none of that appears."""

from __future__ import annotations

import json
from pathlib import Path

from tests.support.swarm_up import Up

LINES = {"world.log": "truav.world DEBUG tick ", "agent0.log": "truav.agent DEBUG uav 0 tick ",
         "agent1.log": "truav.agent DEBUG uav 1 tick ", "recorder.log": "truav.recorder DEBUG recorder: received"}


def _start(tmp: Path, *args: str) -> Up:
    tmp.mkdir()
    return Up(tmp, "verbose", "--agents", "2", "--steps", "5", "--episodes", "1", "--lockstep",
              "--record", str(tmp / "rec.mcap"), *args)


def _ended(ups: list[Up]) -> list[Up]:
    """The swarms started side by side (each with its own router), each waited for; all closed, also when one
    failed (a swarm still running killed with the processes it started)."""
    try:
        for up in ups:
            assert up.wait(timeout=180) == 0, up.output()
    finally:
        for up in ups:
            if up.proc.poll() is None and (up.out / "pids.json").is_file():
                up.pids = json.loads((up.out / "pids.json").read_text())
            up.close()
    return ups


def _logs(up: Up) -> dict[str, str]:
    return {p.name: p.read_text(errors="replace") for p in (up.out / "logs").glob("*.log")}


def test_verbose_adds_debug_lines_to_every_process_and_plain_has_none(tmp_path) -> None:
    plain, verbose, central = _ended([_start(tmp_path / "plain"), _start(tmp_path / "verbose", "-v"),
                                      _start(tmp_path / "central", "-v", "--scheme", "central")])
    for name, text in _logs(plain).items():
        assert " DEBUG " not in text, (name, text)
    assert "debug: supervisor" not in plain.output()
    logs = _logs(verbose)
    for name, line in LINES.items():
        assert line in logs[name], (name, logs[name])
    assert "received actions" in logs["world.log"] and "decided state" in logs["agent0.log"]
    assert "debug: supervisor at" in verbose.output() and "heard step metrics" in verbose.output()
    logs = _logs(central)
    assert "truav.controller DEBUG controller tick " in logs["controller.log"], logs["controller.log"]
    assert "sent commands" in logs["controller.log"]
    assert "truav.agent DEBUG uav 0 tick " in logs["agent0.log"] and "commands so far" in logs["agent0.log"]
    # a readable rate: a line a second at most per call site (a 6-tick run: one each)
    assert logs["world.log"].count("truav.world DEBUG tick ") <= 2

"""`truav log record|play|report|check|recover`: recordings under one noun, and the old spellings as aliases.

`truav report`, `truav-swarm record` and `truav-swarm replay` are aliases of `truav log report`, `record`
and `play`: built by the same parser function (the same flags, help and defaults), running the same
command, the parent's command list calling them "alias of ...". No network: the recording is
synthesised (tests/support/recordings.py), and record/play are exercised up to their
one-line errors, before anything starts.
"""

from __future__ import annotations

import argparse
import filecmp
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.support.readme_commands import README, commands
from tests.support.recordings import make_swarm_recording
from truav.cli.main import build_parser as truav_parser
from truav.cli.main import main as truav_main
from truav.cli.swarm import build_parser as swarm_parser
from truav.cli.swarm import main as swarm_main

REPO = Path(__file__).resolve().parents[2]
LOG_ACTIONS = ("record", "play", "report", "check", "recover", "record-ctl", "cut", "merge", "info", "play-ctl",
               "resim", "ros2bag")
ALIASES = {  # (program, alias) -> the truav log action it names
    ("truav", "report"): "report",
    ("truav-swarm", "record"): "record",
    ("truav-swarm", "replay"): "play",
}


def _subparsers(parser: argparse.ArgumentParser) -> argparse._SubParsersAction:
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))


def _log_parser(action: str) -> argparse.ArgumentParser:
    log = _subparsers(truav_parser()).choices["log"]
    return _subparsers(log).choices[action]


def _alias_parser(program: str, name: str) -> argparse.ArgumentParser:
    return _subparsers(truav_parser() if program == "truav" else swarm_parser()).choices[name]


def _options(parser: argparse.ArgumentParser) -> list[tuple]:
    """Every argument as declared: flags, destination, arity, default, type, choices, help, metavar."""
    return [(tuple(a.option_strings), a.dest, a.nargs, repr(a.default), a.type, a.choices, a.help, a.metavar,
             a.required) for a in parser._actions]


def _help_options(text: str) -> list[str]:
    """The flags a --help text lists (its usage line aside)."""
    body = text.split("\n\n", 1)[1]
    return sorted(set(re.findall(r"(?<![\w-])(--?[A-Za-z][\w-]*)", body)))


@pytest.mark.parametrize("action", LOG_ACTIONS)
def test_every_log_action_has_help(action: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        truav_main(["log", action, "--help"])
    assert done.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: truav log {action} ")


def test_log_group_lists_its_actions(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        truav_main(["log", "--help"])
    out = capsys.readouterr().out
    for action in LOG_ACTIONS:
        assert re.search(rf"^    {action}\s", out, re.M), f"`truav log --help` does not list {action}"


@pytest.mark.parametrize("program,alias", sorted(ALIASES))
def test_alias_takes_the_same_flags_as_its_log_action(program: str, alias: str) -> None:
    new = _log_parser(ALIASES[(program, alias)])
    old = _alias_parser(program, alias)
    assert _options(old) == _options(new)
    assert old.description == new.description
    assert _help_options(old.format_help()) == _help_options(new.format_help())


@pytest.mark.parametrize("program,alias", sorted(ALIASES))
def test_alias_help_in_the_parents_list_names_the_new_spelling(program: str, alias: str) -> None:
    parent = truav_parser() if program == "truav" else swarm_parser()
    line = {a.dest: a.help for a in _subparsers(parent)._choices_actions}[alias]
    assert line == f"alias of `truav log {ALIASES[(program, alias)]}`"
    listed = " ".join(parent.format_help().split())  # the help wraps lines
    assert f"{alias} alias of `truav log {ALIASES[(program, alias)]}`" in listed


def test_replay_help_options_are_play_help_options() -> None:
    def help_of(module: str, *argv: str) -> str:
        done = subprocess.run([sys.executable, "-m", module, *argv, "--help"], cwd=REPO, capture_output=True,
                              text=True, timeout=120)
        assert done.returncode == 0, done.stderr
        return done.stdout

    replay = help_of("truav.cli.swarm", "replay")
    play = help_of("truav.cli", "log", "play")
    assert _help_options(replay) == _help_options(play)
    assert replay.split("\n\n", 1)[1] == play.split("\n\n", 1)[1]  # all but the usage (its program name)


def test_report_alias_and_log_report_give_the_same_report(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "run.mcap"
    make_swarm_recording(path)
    outputs = {}
    for argv, out in ((["report"], tmp_path / "old"), (["log", "report"], tmp_path / "new")):
        assert truav_main([*argv, str(path), "--out", str(out)]) == 0
        captured = capsys.readouterr()
        outputs[out.name] = (captured.out.replace(str(out), "OUT"), captured.err)
    assert outputs["old"] == outputs["new"]
    files = sorted(p.name for p in (tmp_path / "old").iterdir())
    assert files == sorted(p.name for p in (tmp_path / "new").iterdir()) and files
    _, mismatch, errors = filecmp.cmpfiles(tmp_path / "old", tmp_path / "new", files, shallow=False)
    assert not mismatch and not errors


def test_report_alias_and_log_report_fail_alike(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = str(tmp_path / "missing.mcap")
    results = []
    for argv in (["report", missing], ["log", "report", missing]):
        code = truav_main(argv)
        results.append((code, capsys.readouterr().err))
    assert results[0] == results[1] and results[0][0] == 2


def test_log_check_of_the_same_recording(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "run.mcap"
    make_swarm_recording(path)
    runs = []
    for _ in range(2):
        code = truav_main(["log", "check", str(path)])
        runs.append((code, capsys.readouterr()))
    assert runs[0] == runs[1]


def test_record_and_play_stop_at_the_same_mistakes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The new spelling runs the alias's command: the same check, the same exit code, the message
    naming the program it was typed to."""
    out = str(tmp_path / "rec.mcap")
    cases = [
        (["record", "--run", "demo", "--out", out, "--flush-ms", "nan"],
         ["log", "record", "--run", "demo", "--out", out, "--flush-ms", "nan"]),
        (["replay", str(tmp_path / "missing.mcap")], ["log", "play", str(tmp_path / "missing.mcap")]),
    ]
    for old_argv, new_argv in cases:
        old_code = swarm_main(old_argv)
        old_err = capsys.readouterr().err
        new_code = truav_main(new_argv)
        new_err = capsys.readouterr().err
        assert old_code == new_code == 2
        assert old_err.startswith("truav-swarm: error: ") and new_err.startswith("truav: error: ")
        assert old_err.removeprefix("truav-swarm: ") == new_err.removeprefix("truav: ")
    # the recorder's own check (a bad run name), reported by the recorder in both spellings
    bad = ["--run", "bad run", "--out", out]
    assert swarm_main(["record", *bad]) == 2
    old_err = capsys.readouterr().err
    assert truav_main(["log", "record", *bad]) == 2
    assert capsys.readouterr().err == old_err and old_err.startswith("recorder: error: ")
    assert not Path(out).exists()


def test_log_play_checks_endpoints_as_truav_swarm_does(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "run.mcap"
    make_swarm_recording(path)
    old_code = swarm_main(["replay", str(path), "-e", "nonsense"])
    old_err = capsys.readouterr().err
    new_code = truav_main(["log", "play", str(path), "-e", "nonsense"])
    new_err = capsys.readouterr().err
    assert old_code == new_code == 2
    assert old_err.removeprefix("truav-swarm: ") == new_err.removeprefix("truav: ")


def test_the_docs_name_the_log_group_and_its_aliases() -> None:
    """The recording tutorial (the README links it) names every `truav log` action and alias; the commands
    of the README and the docs pages use them all, and each parses."""
    text = (README.parent / "docs" / "tutorials" / "record-replay-resim.md").read_text()
    for spelling in (*(f"truav log {a}" for a in LOG_ACTIONS), "truav report", "truav-swarm record",
                     "truav-swarm replay"):
        assert f"`{spelling}" in text or f"{spelling} " in text, f"the recording tutorial does not mention {spelling}"
    assert "`truav report` is `truav log report`" in " ".join(text.split())
    log_commands = [c for c in commands() if c[:2] == ["truav", "log"]]
    assert {c[2] for c in log_commands} == set(LOG_ACTIONS)
    for argv in log_commands:  # each parses with the real parser
        truav_parser().parse_args(argv[1:])


def test_replay_ctl_is_play_ctl() -> None:
    """`truav-swarm replay-ctl` and `truav log play-ctl` are one parser and one command (its actions are
    subcommands, which the flag comparison above cannot hold side by side)."""
    from truav.cli.swarm import build_parser as swarm_parser

    for argv in (["seek", "--tick", "40"], ["rate", "2"], ["step"], ["burst", "5"], ["status"], ["seek", "--by", "-5"]):
        old = vars(swarm_parser().parse_args(["replay-ctl", "--run", "r", *argv]))
        new = vars(truav_parser().parse_args(["log", "play-ctl", "--run", "r", *argv]))
        assert {k: v for k, v in old.items() if k not in ("func", "ctl_prog", "command")} == \
            {k: v for k, v in new.items() if k not in ("func", "ctl_prog", "command", "log_command")}

"""`--version` on every command: a researcher reports which TRUAV made a result."""

from __future__ import annotations

import argparse
from importlib import metadata

import pytest

from truav.cli import main as truav_main
from truav.cli import swarm as truav_swarm
from truav.cli import swarm_router, log_process


def _parsers(parser: argparse.ArgumentParser, prog: str):
    yield prog, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, f"{prog} {name}")


def _all_parsers():
    yield from _parsers(truav_main.build_parser(), "truav")
    yield from _parsers(truav_swarm.build_parser(), "truav-swarm")


def test_every_command_and_subcommand_prints_the_installed_version(capsys):
    expected = metadata.version("truav")
    seen = 0
    for prog, parser in _all_parsers():
        with pytest.raises(SystemExit) as exit_:
            parser.parse_args(["--version"])
        assert exit_.value.code == 0, prog
        out = capsys.readouterr().out.strip()
        assert out.endswith(f" {expected}"), (prog, out)
        seen += 1
    assert seen > 30  # the walk reached the subcommands, not only the two programs


@pytest.mark.parametrize("main", [swarm_router.main, log_process.main])
def test_the_light_parsers_answer_too(main, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.strip().endswith(metadata.version("truav"))

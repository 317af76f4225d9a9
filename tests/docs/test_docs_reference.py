"""The generated reference pages (docs/reference/cli.md, config.md) say what the code does now: a flag, a
help text, a default, a config key, its range or its doc changed without regenerating the pages fails here."""

from __future__ import annotations

import argparse
import os
from dataclasses import dataclass, field

import pytest

from truav.cli import reference as cli_reference
from truav.cli.reference import COMMAND, PAGES, cli_page, config_page, fault_plan_page


@pytest.mark.parametrize("name", ["cli.md", "config.md", "fault-plan-format.md", "agent-api.md",
                                  "pettingzoo-observation.md"])
def test_committed_page_is_what_the_code_makes(name: str) -> None:
    fresh = cli_reference.pages()[name]
    committed = (PAGES / name).read_text() if (PAGES / name).exists() else ""
    assert committed == fresh, f"docs/reference/{name} is out of date with the code; regenerate: {COMMAND}"


def _toy_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="toy", description="A toy.")
    sub = ap.add_subparsers(dest="command")
    run = sub.add_parser("run", aliases=["go"], help="run it")
    run.add_argument("--speed", type=float, default=15.0, help="m/s (default %(default)s)")
    run.add_argument("--mode", choices=("a", "b"), default="a", help="which | mode")
    run.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    run.add_argument("--quiet", action="store_true", help="no bar")
    return ap


def test_cli_page_lists_every_subcommand_flag_help_and_default() -> None:
    page = cli_page([("toy", _toy_parser)])
    assert "### `toy run`" in page and "(also: `go`)" in page
    assert "| `--speed SPEED` | m/s (default 15.0) | `15.0` |" in page  # %(default)s expanded
    assert "which \\| mode (one of: a, b)" in page  # a pipe in help cannot break the table
    assert "| `--quiet` | no bar |  |" in page  # a flag has no default to show
    # the number of cores is not written into the page: it would differ from machine to machine
    assert "| `--workers WORKERS` |  | the machine's cores |" in page


@dataclass(frozen=True)
class _Section:
    """A section."""

    speed: float = field(default=15.0, metadata={"range": (0.1, 100.0)})
    """Top speed (m/s).
    Paper: 15."""
    name: str = "x"


@dataclass(frozen=True)
class _Toy:
    motion: _Section = field(default_factory=_Section)


SOURCE = '''
class _Section:
    """A section."""

    speed: float = field(default=15.0, metadata={"range": (0.1, 100.0)})
    """Top speed (m/s).
    Paper: 15."""
    name: str = "x"
'''


def test_config_page_has_each_key_with_default_range_and_its_docstring() -> None:
    page = config_page(_Toy, SOURCE)
    assert "## `[motion]`" in page and "A section." in page
    assert "| `motion.speed` | `15.0` | 0.1 .. 100 | Top speed (m/s). Paper: 15. |" in page
    assert '| `motion.name` | `"x"` |  |  |' in page


def test_check_mode_names_the_command_that_regenerates(tmp_path, monkeypatch, capsys) -> None:
    monkeypatch.setattr(cli_reference, "PAGES", tmp_path)
    monkeypatch.setattr(cli_reference, "pages", lambda: {"cli.md": "new\n"})
    (tmp_path / "cli.md").write_text("old\n")
    assert cli_reference.main(["--check"]) == 1
    assert COMMAND in capsys.readouterr().err
    assert cli_reference.main([]) == 0 and (tmp_path / "cli.md").read_text() == "new\n"
    assert cli_reference.main(["--check"]) == 0


def test_fault_plan_page_shows_the_docstrings_example_as_toml() -> None:
    doc = """Plans.

    A plan is TOML:

        [[fault]]
        kind = "loss"

        [[fault]]
        kind = "crash"

    Crashes are real signals.
    """
    page = fault_plan_page(doc)
    assert '```toml\n[[fault]]\nkind = "loss"\n\n[[fault]]\nkind = "crash"\n```\n\nCrashes are real signals.' in page

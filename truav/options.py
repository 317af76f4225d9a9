"""One declaration per process option: its flag, help, default, check and place in a child's argv.

A process's options dataclass (AgentOptions, WorldOptions, ControllerOptions) declares a field
with :func:`opt` instead of a bare default::

    checkpoint_every: int = opt(100, flag="--checkpoint-every", type="positive_int",
                                help="steps between checkpoints (default 100)")

The command line adds the flag from it (``truav.cli.args.add_options``) and fills the dataclass
from the parsed flags (``truav.cli.args.options_from``); the supervisor builds the child's argv
from an options object with :func:`to_argv`. ``type`` names one of the argument checks of
truav.cli.args (``"positive_int"``, ...): this base module imports no argparse and no CLI.
"""

from __future__ import annotations

import dataclasses
from typing import Any

FLAG = "truav.flag"
"""The key of a field's metadata that holds its :class:`Flag`."""


@dataclasses.dataclass(frozen=True)
class Flag:
    """How a field is spelled on a command line (everything argparse needs but the default)."""

    flag: str
    help: str | None = None
    type: str | None = None
    """The name of an argument check in truav.cli.args (its argparse ``type``); None: a string."""
    metavar: str | None = None
    choices: tuple | None = None
    action: str | None = None
    """``"store_true"`` for a switch; None: the flag takes a value."""

    @property
    def dest(self) -> str:
        """argparse's attribute name for the flag (``--beacon-cell`` -> ``beacon_cell``)."""
        return self.flag.lstrip("-").replace("-", "_")


def opt(default: Any = None, *, flag: str, help: str | None = None, type: str | None = None,  # noqa: A002
        metavar: str | None = None, choices: tuple | None = None, action: str | None = None) -> Any:
    """A dataclass field with ``default`` that is also the command-line flag ``flag``."""
    return dataclasses.field(default=default, metadata={FLAG: Flag(flag, help, type, metavar,
                                                                   tuple(choices) if choices else None, action)})


def flag_of(cls_or_options, name: str) -> Flag:
    """The :class:`Flag` declared for field ``name`` (KeyError: the field has none)."""
    for f in dataclasses.fields(cls_or_options):
        if f.name == name:
            if FLAG not in f.metadata:
                raise KeyError(f"{name}: declared without a flag (use truav.options.opt)")
            return f.metadata[FLAG]
    raise KeyError(f"{name}: no such field")


def declared(cls_or_options, names=None) -> list[tuple[str, Flag, Any]]:
    """``(field name, flag, default)`` of the fields ``names`` (in that order), or of every field that
    has a flag (in declaration order)."""
    fields = {f.name: f for f in dataclasses.fields(cls_or_options)}
    if names is None:
        names = [n for n, f in fields.items() if FLAG in f.metadata]
    return [(n, flag_of(cls_or_options, n), fields[n].default) for n in names]


def to_argv(options, names) -> list[str]:
    """The flags of ``options``'s fields ``names`` as a child's argv: a switch when it is on, a value
    flag with ``str(value)`` unless the value is None."""
    argv: list[str] = []
    for name, flag, _ in declared(options, names):
        value = getattr(options, name)
        if flag.action == "store_true":
            if value:
                argv.append(flag.flag)
        elif value is not None:
            argv += [flag.flag, str(value)]
    return argv

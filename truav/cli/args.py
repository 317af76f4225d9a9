"""Validation shared by the `truav` and `truav-swarm` command lines.

A user mistake (a bad flag value, a missing or malformed file, an output
path that cannot be written) is a :class:`UserError`: the top-level handler
of each ``main()`` prints it as one line naming the flag or file and exits
with code 2, before anything starts.  Everything else (a bug) keeps its
traceback.  The argparse types here reject bad values at parse time, so the
rest of the code never sees them; :class:`OneLineParser` makes argparse's own
errors one line too.  :func:`add_transport_args` adds the zenoh transport flags every bus
command shares (their values become a config in :mod:`truav.bus.zenoh_config`).
"""

from __future__ import annotations

import argparse
import math
import os
import re
import signal
import sys
from pathlib import Path
from typing import Callable, NoReturn

from truav.checks import (  # noqa: F401  (re-exported: the command lines take their checks from here)
    check_endpoint, check_in_file, check_out_dir, check_out_file, make_dir)
from truav import options
from truav.atomic import no_space
from truav.lifecycle import signals_handled
from truav.stopping import (exit_code_for, forget_stop_signal, is_interrupt, note_stop_signal, signal_name,
                            stopped_by)
from truav.errors import EXIT_BROKEN_PIPE, EXIT_USAGE, UserError  # noqa: F401

MAX_SEED = 2**63 - 1
"""Seeds feed numpy's SeedSequence, which takes any non-negative integer; this keeps them in an int64."""


def truav_version() -> str:
    """The installed distribution's version (declared once, in pyproject.toml)."""
    from importlib import metadata
    try:
        return metadata.version("truav")
    except metadata.PackageNotFoundError:  # run from a source tree that was never installed
        return "unknown (not installed: pip install -e .)"


class _VersionAction(argparse.Action):
    """``--version``: looked up only when asked, so building the ~60 parsers costs no metadata read."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        parser._print_message(f"{parser.prog} {truav_version()}\n", sys.stdout)  # stdout, as argparse's own
        parser.exit(0)


class OneLineParser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (the flag and what is wrong) and exit code 2; every command
    and subcommand answers ``--version``."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        if self.add_help:
            self.add_argument("--version", action=_VersionAction, help="print TRUAV's version and exit")

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _stop_as_ctrl_c(signum: int, frame) -> None:
    """SIGTERM and SIGHUP stop a command as Ctrl-C does (schedulers send SIGTERM, a closed terminal SIGHUP):
    the handler in force for SIGINT runs (the trainer's: checkpoint at the episode's end), else
    KeyboardInterrupt."""
    note_stop_signal(signum)
    handler = signal.getsignal(signal.SIGINT)
    if callable(handler) and handler is not signal.default_int_handler:
        handler(signum, frame)
    else:
        raise KeyboardInterrupt


def _signal_exit(code: int) -> int:
    """130 (a stop) becomes the code of the signal that stopped the command: 143 for SIGTERM, 129 for SIGHUP."""
    return exit_code_for(stopped_by()) if code == 130 and stopped_by() is not None else code


def run_main(prog: str, body: Callable[[], int], say_interrupted: bool = True) -> int:
    """Run a command: a UserError becomes one line + exit 2, Ctrl-C exit 130 (SIGTERM 143, SIGHUP 129),
    and a closed stdout (``| head``) ends quietly, as Unix tools do."""
    forget_stop_signal()
    with signals_handled((signal.SIGTERM, signal.SIGHUP), _stop_as_ctrl_c):
        try:
            return _signal_exit(body())
        except UserError as exc:
            print(f"{prog}: error: {exc}", file=sys.stderr)
            return EXIT_USAGE
        except (KeyboardInterrupt, SystemError) as exc:
            if not is_interrupt(exc):
                raise
            if say_interrupted:
                print(f"{prog}: stopped by {signal_name(stopped_by() or signal.SIGINT)}", file=sys.stderr)
            return _signal_exit(130)
        except BrokenPipeError:
            # The reader went away: point stdout at /dev/null so the interpreter's final flush
            # does not raise again (the recipe of the Python docs, "Note on SIGPIPE").
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
            return EXIT_BROKEN_PIPE
        except OSError as exc:  # a full disk: one line, exit 1 (not the user's mistake)
            if not no_space(exc):
                raise
            where = Path(exc.filename).absolute().parent if exc.filename else "the disk it writes to"
            print(f"{prog}: error: no space left on {where}", file=sys.stderr)
            return 1


# -- argparse types ------------------------------------------------------------------
def _int(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None


def int_in(lo: int, hi: int | None = None) -> Callable[[str], int]:
    """argparse type: an integer in [lo, hi]."""
    def parse(text: str) -> int:
        value = _int(text)
        if value < lo or (hi is not None and value > hi):
            bound = f">= {lo}" if hi is None else f"in [{lo}, {hi}]" if hi < 2**31 else f">= {lo} and < 2**63"
            raise argparse.ArgumentTypeError(f"must be an integer {bound}, got {value}")
        return value
    return parse


positive_int = int_in(1)
"""argparse type: an integer >= 1."""
non_negative_int = int_in(0)
"""argparse type: an integer >= 0."""
seed_int = int_in(0, MAX_SEED)
"""argparse type: a seed (an integer >= 0)."""


tcp_port = int_in(0, 65535)
"""argparse type: a TCP port number (0: any free port)."""


def _finite_float(text: str, allow_zero: bool) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and (value > 0 or (allow_zero and value == 0))):
        raise argparse.ArgumentTypeError(f"must be a finite number {'>=' if allow_zero else '>'} 0, got {text}")
    return value


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    return _finite_float(text, allow_zero=False)


def non_negative_float(text: str) -> float:
    """argparse type: a finite number >= 0."""
    return _finite_float(text, allow_zero=True)


def share(text: str) -> float:
    """argparse type: a number in [0, 1]."""
    value = non_negative_float(text)
    if value > 1.0:
        raise argparse.ArgumentTypeError(f"must be in [0, 1], got {text}")
    return value


def run_name(text: str) -> str:
    """argparse type: a run name, as the bus keys allow (truav/<run>/...)."""
    from truav.wire import keys
    try:
        return keys.validate_run(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def snapshot_window(text: str) -> str:
    """argparse type: ``BEFORE_S:AFTER_S`` (recorder snapshot mode), both > 0; kept as text."""
    from recorder.record_modes import parse_snapshot
    try:
        parse_snapshot(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def add_transport_args(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the zenoh-example style flags ``-e/--connect``, ``-l/--listen``, ``-c/--config``, ``-m/--mode``."""
    from truav.bus.zenoh_config import DEFAULT_ENDPOINT, MODES  # deferred: zenoh is imported only by bus commands
    group = parser.add_argument_group("zenoh transport")
    group.add_argument("-e", "--connect", metavar="ENDPOINT", action="append", default=[],
                       help=f"endpoint to connect to (repeatable; client default {DEFAULT_ENDPOINT})")
    group.add_argument("-l", "--listen", metavar="ENDPOINT", action="append", default=[],
                       help="endpoint to listen on (repeatable)")
    group.add_argument("-c", "--config", metavar="FILE", default=None, help="zenoh JSON5 config file")
    group.add_argument("-m", "--mode", choices=MODES, default=None,
                       help="zenoh session mode (default: client, or the config file's)")
    group.add_argument("--creds", metavar="DIR", default=None,
                       help="credentials directory of a --secure swarm (truav-swarm certs): use this "
                            "component's certificate and zenoh config from it (instead of -c)")
    return parser


def check_transport(args, listen_flag: str = "-l/--listen") -> None:
    """The zenoh-example flags: endpoints well formed, a -c file Zenoh can read."""
    connect = getattr(args, "connect", None) or []
    for ep in [connect] if isinstance(connect, str) else connect:  # `certs -e` takes one endpoint
        check_endpoint("-e/--connect", ep)
    for ep in getattr(args, "listen", None) or []:
        check_endpoint(listen_flag, ep)
    if not isinstance(connect, str):
        check_tls_creds(args)
    if getattr(args, "config", None) is not None:
        check_in_file("-c/--config", args.config)
        import zenoh  # deferred: `truav --help` and the pure commands do not load it
        try:
            zenoh.Config.from_file(args.config)
        except zenoh.ZError as exc:
            raise UserError(f"-c/--config {args.config}: not a Zenoh config ({_one_line(exc)})") from None


def check_tls_creds(args, flag: str = "-e/--connect") -> None:
    """A tls/ endpoint is a --secure swarm's router: without this component's certificate (--creds or
    -c) Zenoh only says it cannot connect, so say what is missing, before connecting."""
    if getattr(args, "creds", None) or getattr(args, "config", None):
        return
    for ep in getattr(args, "connect", None) or []:
        if isinstance(ep, str) and ep.startswith("tls/"):
            raise UserError(f"{flag} {ep}: a TLS router (a --secure swarm) admits only clients with its "
                            f"credentials: pass --creds DIR (the run's <out>/creds)")


def _one_line(exc: Exception) -> str:
    """A Zenoh config error on one line: json5's multi-line caret diagram becomes "line L:C: what"."""
    text = str(exc).split(" at /")[0].strip()
    where = re.search(r"-->\s*(\d+:\d+)", text)
    what = re.findall(r"^\s*=\s*(.+?)\)?\s*$", text, flags=re.M)
    if where and what:
        return f"line {where.group(1)}: {what[-1]}"
    return " ".join(text.split())


# -- options declared once (truav.options): their flags and their dataclasses --------
def _option_types() -> dict[str, Callable[[str], object]]:
    """The argument checks a declaration names in its ``type`` (truav.options.opt)."""
    return {"positive_int": positive_int, "non_negative_int": non_negative_int, "seed_int": seed_int,
            "positive_float": positive_float, "non_negative_float": non_negative_float, "share": share,
            "run_name": run_name, "tcp_port": tcp_port, "snapshot_window": snapshot_window}


def add_options(parser: argparse.ArgumentParser, cls, names=None, **defaults) -> None:
    """Add the flags declared in the dataclass ``cls`` (the fields ``names``, in that order; None:
    every field declared with a flag), each with its declared help, type, metavar and default
    (``defaults``: another default for a field, by name, as `up` has for some)."""
    types = _option_types()
    for name, flag, default in options.declared(cls, names):
        kwargs: dict = {"help": flag.help}
        if flag.action is not None:
            kwargs["action"] = flag.action
        else:
            kwargs["default"] = defaults.get(name, default)
            if flag.type is not None:
                kwargs["type"] = types[flag.type]
            if flag.metavar is not None:
                kwargs["metavar"] = flag.metavar
            if flag.choices is not None:
                kwargs["choices"] = flag.choices
        parser.add_argument(flag.flag, **kwargs)


def options_from(cls, namespace: argparse.Namespace, **overrides):
    """An instance of the dataclass ``cls``: its flag-declared fields from the parsed ``namespace``
    (those the parser has), the rest from ``overrides`` (which also win over the namespace)."""
    values = {name: getattr(namespace, flag.dest) for name, flag, _ in options.declared(cls)
              if hasattr(namespace, flag.dest)}
    values.update(overrides)
    return cls(**values)

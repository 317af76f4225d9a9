"""Validation shared by the `truav` and `truav-swarm` command lines.

A user mistake (a bad flag value, a missing or malformed file, an output
path that cannot be written) is a :class:`UserError`: the top-level handler
of each ``main()`` prints it as one line naming the flag or file and exits
with code 2, before anything starts.  Everything else (a bug) keeps its
traceback.  The argparse types here reject bad values at parse time, so the
rest of the code never sees them; :class:`OneLineParser` makes argparse's own
errors one line too.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import signal
import sys
import tempfile
from pathlib import Path
from typing import Callable, NoReturn

EXIT_USAGE = 2
EXIT_BROKEN_PIPE = 128 + signal.SIGPIPE
"""What a shell reports for a Unix tool killed by SIGPIPE (`truav log check FILE | head`)."""

MAX_SEED = 2**63 - 1
"""Seeds feed numpy's SeedSequence, which takes any non-negative integer; this keeps them in an int64."""


class UserError(ValueError):
    """A user mistake: the message names the flag or file and says what is wrong."""


class OneLineParser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (the flag and what is wrong) and exit code 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def run_main(prog: str, body: Callable[[], int], say_interrupted: bool = True) -> int:
    """Run a command: a UserError becomes one line + exit 2, Ctrl-C exit 130, and a closed
    stdout (``| head``) ends quietly, as Unix tools do."""
    try:
        return body()
    except UserError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        if say_interrupted:
            print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader went away: point stdout at /dev/null so the interpreter's final flush
        # does not raise again (the recipe of the Python docs, "Note on SIGPIPE").
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return EXIT_BROKEN_PIPE


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
    from truav.bus import keys
    try:
        return keys.validate_run(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


_ENDPOINT = re.compile(r"^(?P<proto>[a-z][a-z0-9+-]*)/(?P<address>[^?#\s]+)(\?[^#\s]*)?(#\S*)?$")
_HOST_PORT_PROTOCOLS = {"tcp", "udp", "tls", "quic", "ws"}


def check_endpoint(flag: str, text: str, tcp_only: bool = False) -> str:
    """A Zenoh locator ``<protocol>/<address>[?metadata][#config]``; host:port for IP protocols."""
    m = _ENDPOINT.match(text)
    if not m:
        raise UserError(f"{flag} {text!r}: not a Zenoh endpoint (expected e.g. tcp/127.0.0.1:7447)")
    proto, address = m["proto"], m["address"]
    if tcp_only and proto != "tcp":
        raise UserError(f"{flag} {text!r}: must be a tcp/HOST:PORT endpoint here")
    if proto in _HOST_PORT_PROTOCOLS:
        host, _, port = address.rpartition(":")
        if not host or not port.isdigit() or not 0 <= int(port) <= 65535:
            raise UserError(f"{flag} {text!r}: expected {proto}/HOST:PORT with a port in [0, 65535]")
    return text


# -- files ---------------------------------------------------------------------------
def check_in_file(flag: str, path: str) -> Path:
    """An existing, readable regular file."""
    p = Path(path)
    if not path:
        raise UserError(f"{flag}: empty path")
    if not p.exists():
        raise UserError(f"{flag} {path}: no such file")
    if not p.is_file():
        raise UserError(f"{flag} {path}: not a regular file")
    if not os.access(p, os.R_OK):
        raise UserError(f"{flag} {path}: not readable")
    return p


def _writable_parent(flag: str, path: str, p: Path) -> None:
    """The nearest existing ancestor of ``p`` must be a writable directory (so p can be created)."""
    for parent in [p.absolute(), *p.absolute().parents]:
        if parent.exists():
            if not parent.is_dir():
                raise UserError(f"{flag} {path}: {parent} is not a directory")
            if not os.access(parent, os.W_OK | os.X_OK):
                raise UserError(f"{flag} {path}: {parent} is not writable")
            _probe_write(flag, path, parent)
            return


def _probe_write(flag: str, path: str, directory: Path) -> None:
    """Create and remove a file in ``directory``: os.access says yes to root everywhere, but /proc, a
    read-only mount or a full disk still refuse, and that should be found before anything starts."""
    try:
        fd, probe = tempfile.mkstemp(prefix=".truav-probe-", dir=directory)
    except OSError as exc:
        raise UserError(f"{flag} {path}: cannot write in {directory} ({exc.strerror or exc})") from None
    os.close(fd)
    os.unlink(probe)


def check_out_dir(flag: str, path: str) -> Path:
    """A directory that exists or can be created (its existing contents are the caller's business)."""
    if not path:
        raise UserError(f"{flag}: empty path (give a directory)")
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise UserError(f"{flag} {path}: exists and is not a directory")
    _writable_parent(flag, path, p)
    return p


def check_out_file(flag: str, path: str) -> Path:
    """A file path that can be created: not a directory, under a directory that exists or can be made."""
    if not path:
        raise UserError(f"{flag}: empty path (give a file)")
    p = Path(path)
    if p.is_dir():
        raise UserError(f"{flag} {path}: is a directory")
    _writable_parent(flag, path, p.parent)
    return p


def make_dir(flag: str, path: str | Path) -> Path:
    """mkdir -p, with a failure as a UserError naming the flag (a full disk, a race with a file)."""
    p = Path(path)
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{flag} {path}: cannot create the directory ({exc.strerror or exc})") from None
    return p

"""Checks of files, directories and endpoints a user names, each failing as a :class:`UserError`
that names the flag: shared by the command lines and by the code that opens run directories."""

from __future__ import annotations

import os
import re
import tempfile
from pathlib import Path

from truav.errors import UserError


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


def check_federated(cfg, scheme: str, learns: bool) -> None:
    """Q-sharing (``federated.every`` > 0) only where TRUAV agents learn: another scheme or greedy agents would
    share nothing, while the run's summary still said federated."""
    every = cfg.federated.every
    if every <= 0:
        return
    if scheme != "truav":
        raise UserError(f"federated.every = {every}: only --scheme truav agents share Q rows (this is --scheme "
                        f"{scheme}); set it to 0 or drop it")
    if not learns:
        raise UserError(f"federated.every = {every}: --greedy agents do not learn, so share nothing; drop --greedy "
                        f"or federated.every")

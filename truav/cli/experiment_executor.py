"""--executor and --address of the experiment commands (local process pool or Ray),
and the checks run on them before any work starts.
"""

from __future__ import annotations

import argparse
import importlib.util
import re
import socket

from truav.cli.config import UsageError


def add_executor_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--executor", choices=("local", "ray"), default="local",
                   help="local: a pool of worker processes (default); ray: cells as Ray tasks (extra `ray`)")
    p.add_argument("--address", help="with --executor ray: the cluster to join, e.g. HEAD:6379 "
                                     "(default: start a local Ray instance of --workers CPUs)")


def check_executor(args) -> None:
    if args.address and args.executor != "ray":
        raise UsageError("--address needs --executor ray")
    if args.executor == "ray" and importlib.util.find_spec("ray") is None:
        raise UsageError("--executor ray needs Ray: pip install -e '.[ray]'")
    if args.address:
        check_ray_address(args.address)


RAY_ADDRESS_RE = re.compile(r"(?:ray://)?(?P<host>[A-Za-z0-9._-]+|\[[0-9A-Fa-f:]+\]):(?P<port>[0-9]{1,5})")
RAY_PROBE_TIMEOUT_S = 3.0
"""How long --address's head may take to accept a TCP connection: ray.init itself waits minutes."""


def check_ray_address(address: str, flag: str = "--address") -> None:
    """--address is `auto` (RAY_ADDRESS or a cluster started here) or HOST:PORT / ray://HOST:PORT of a
    head that accepts connections: checked before anything runs, as ray.init would hang on it."""
    if address == "auto":
        return
    m = RAY_ADDRESS_RE.fullmatch(address)
    if m is None or not 0 < int(m.group("port")) < 65536:
        raise UsageError(f"{flag} {address}: expected HOST:PORT, ray://HOST:PORT or auto (e.g. HEAD:6379)")
    host = m.group("host").strip("[]")
    try:
        socket.create_connection((host, int(m.group("port"))), timeout=RAY_PROBE_TIMEOUT_S).close()
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__.replace("Error", " error").lower()
        raise UsageError(f"{flag} {address}: no Ray head answers there ({reason})") from None

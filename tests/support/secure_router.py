"""A loopback TLS router under a run's access control (`truav-swarm certs`' credentials) and bare zenoh
sessions as its identities: what Zenoh itself enforces under --secure, not the application."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import zenoh

from tests.support.waits import free_port, wait_until
from truav.bus import security


@contextmanager
def secure_router(d: Path, run: str, n: int) -> Iterator[Any]:
    """Credentials for ``run`` of ``n`` UAVs issued into ``d``, their router open on a free loopback port
    while in the block; yields the loaded credentials."""
    security.issue(d, run, n, f"tcp/127.0.0.1:{free_port()}")
    router = zenoh.open(zenoh.Config.from_file(str(d / security.ROUTER_CONFIG)))
    try:
        yield security.load(d, run)
    finally:
        router.close()


def client(creds: Any, identity: str) -> zenoh.Session:
    """A zenoh session as ``identity``, with its certificate."""
    return zenoh.open(zenoh.Config.from_file(str(creds.config_file(identity))))


def until(pred: Callable[[], bool], timeout: float = 5.0) -> bool:
    """``pred`` polled until it holds (a put reaches a subscriber in ~1 ms) or ``timeout`` s pass."""
    return wait_until(pred, timeout)

"""Waiting without fixed sleeps, and free loopback ports."""

from __future__ import annotations

import socket
import time
from collections.abc import Callable

from truav.bus.transport import Bus


def wait_until(pred: Callable[[], bool], timeout_s: float, poll_s: float = 0.01) -> bool:
    """Poll ``pred`` until it holds or ``timeout_s`` passes; its last value."""
    deadline = time.monotonic() + timeout_s
    while not pred() and time.monotonic() < deadline:
        time.sleep(poll_s)
    return pred()


def wait_matched(sender, key: str, timeout_s: float = 30.0) -> bool:
    """Wait until ``sender`` (a zenoh Session or a Bus) knows of a subscriber to ``key``: the subscription
    has reached the router and the router has told the sender. A fixed sleep for that (0.3 s) was too
    short on a loaded machine, and a put before it is dropped."""
    if isinstance(sender, Bus):
        return sender.await_subscribers(key, timeout_s)
    pub = sender.declare_publisher(key)
    try:
        return wait_until(lambda: pub.matching_status.matching, timeout_s, poll_s=0.02)
    finally:
        pub.undeclare()


def free_port() -> int:
    """A free TCP port on loopback (bound once, then released)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]

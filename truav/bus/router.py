"""An in-process Zenoh router (zenoh-python 1.x can open a session in ``router`` mode) for
``truav-swarm router`` and the tests: it drops, at ingress, a put larger than its key's kind may be."""

from __future__ import annotations

import json
import logging
import os
import threading
from collections.abc import Callable, Sequence

import zenoh

from truav import jsonio
from truav.bus.bus_types import BUS_LOGGER
from truav.bus.placement import KIND_BY_KEY
from truav.bus.zenoh_config import DEFAULT_ENDPOINT, MODE_ROUTER, close_session, make_config, open_session
from truav.wire import keys, schema

log = logging.getLogger(BUS_LOGGER)

ROUTER_POLL_S = 0.5

# Zenoh counts payload + attachment against a low-pass limit; ours carry at most a short replay tag.
ROUTER_SIZE_SLACK_BYTES = 1024


def router_size_filters() -> list[dict]:
    """Zenoh ``low_pass_filter`` items: the router drops, on ingress from any link, a put larger
    than its key's message kind may be (:func:`truav.wire.schema.size_limit`), so an oversized
    payload costs one router check instead of a copy to every subscriber."""
    by_limit: dict[int, list[str]] = {}
    for parts, kind in KIND_BY_KEY.items():
        if parts[0] == keys.UAV:
            expr = f"{keys.ROOT}/*/{keys.UAV}/*/{parts[1]}"
            if parts[1] == keys.BEACON:  # range-limited beacons, under their map cell
                by_limit.setdefault(schema.size_limit(kind), []).append(f"{expr}/*")
        elif len(parts) == 2:
            expr = f"{keys.ROOT}/*/{parts[0]}/{parts[1]}"
        else:
            expr = f"{keys.ROOT}/*/{parts[0]}/**"
        by_limit.setdefault(schema.size_limit(kind), []).append(expr)
    by_limit.setdefault(schema.MAX_PAYLOAD_BYTES, []).append(f"{keys.ROOT}/**")  # anything else under truav
    return [{"id": f"truav-size-{limit}", "flows": ["ingress"], "messages": ["put"],
             "key_exprs": sorted(exprs), "size_limit": limit + ROUTER_SIZE_SLACK_BYTES}
            for limit, exprs in sorted(by_limit.items())]


ROUTER_SESSION_LIMITS = {
    "transport/unicast/max_sessions": 4 * keys.MAX_UAVS + 64,  # every agent its own session, and the rest
    "transport/unicast/accept_pending": 1024,  # a thousand agents connect within seconds of each other
    "transport/unicast/accept_timeout": 60_000,
}
"""What a router accepts: Zenoh's defaults (1,000 sessions, 100 pending, 10 s) refuse the sessions of a
1,000-UAV swarm starting at once on a busy 2-core machine. A config file's own values are kept."""
ZENOH_DEFAULT_LIMITS = {"transport/unicast/max_sessions": 1000, "transport/unicast/accept_pending": 100,
                        "transport/unicast/accept_timeout": 10_000}


def open_router(
    listen: Sequence[str] = (DEFAULT_ENDPOINT,),
    connect: Sequence[str] = (),
    config_file: str | os.PathLike[str] | None = None,
) -> zenoh.Session:
    """Open a session in Zenoh ``router`` mode (zenoh-python 1.x supports it); caller closes it.

    Unless the config file sets its own ``low_pass_filter``, the router gets
    :func:`router_size_filters` (plain and secure alike)."""
    conf = make_config(MODE_ROUTER, connect, listen, config_file)
    if json.loads(conf.get_json("low_pass_filter") or "[]") == []:
        conf.insert_json5("low_pass_filter", jsonio.dumps(router_size_filters()))
    for path, value in ROUTER_SESSION_LIMITS.items():  # Zenoh's defaults stop a swarm short of 1,000 UAVs
        if json.loads(conf.get_json(path) or "null") == ZENOH_DEFAULT_LIMITS[path]:
            conf.insert_json5(path, jsonio.dumps(value))
    return open_session(conf)


def run_router(
    listen: Sequence[str] = (DEFAULT_ENDPOINT,),
    *,
    connect: Sequence[str] = (),
    config_file: str | os.PathLike[str] | None = None,
    stop: threading.Event | None = None,
    on_ready: Callable[[], None] | None = None,
) -> None:
    """Run a Zenoh router until ``stop`` is set (or Ctrl-C), for ``truav-swarm router``;
    ``on_ready()`` is called once it listens."""
    stop = stop if stop is not None else threading.Event()
    session = open_router(listen, connect, config_file)  # a ZError here: it could not listen
    try:
        log.info("zenoh router %s listening on %s", session.zid(), ", ".join(listen) or "config endpoints")
        if on_ready is not None:
            on_ready()
        try:
            while not stop.wait(ROUTER_POLL_S):
                pass
        except KeyboardInterrupt:
            log.info("router interrupted")
    finally:
        close_session(session, "router")  # a close that times out is not an error of the run
    log.info("zenoh router stopped")

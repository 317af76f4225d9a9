"""Zenoh session configs for TRUAV processes, multicast scouting always off.

:func:`make_config` builds a ``zenoh.Config`` (defaults loopback-only: clients connect to, and the router
listens on, :data:`DEFAULT_ENDPOINT`); :func:`config_from_args` and :func:`apply_creds` read the values of
the shared transport flags (``truav.cli.args.add_transport_args``) from a parsed namespace;
:func:`open_session` opens a session with the lean Zenoh runtime."""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Sequence
from typing import Any

import zenoh

from truav.bus.acl import CredentialsError, replay_run
from truav.bus.certs import load as load_credentials
from truav.bus.secure_configs import TLS_FILE_KEYS
from truav import jsonio

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
DEFAULT_PEER_LISTEN = "tcp/127.0.0.1:0"
MODE_CLIENT = "client"
MODE_PEER = "peer"
MODE_ROUTER = "router"
MODES = (MODE_CLIENT, MODE_PEER, MODE_ROUTER)

ZENOH_RUNTIME_ENV = "ZENOH_RUNTIME"
LEAN_ZENOH_RUNTIME = "(rx: (worker_threads: 1))"
"""Zenoh's receive runtime with one worker thread instead of two.  A swarm on a
few cores runs 20+ processes; with two rx workers each message also wakes the
second one.  Measured with ``bench/bench_swarm.py`` (20 agents, 2 cores): 35k
-> 26k context switches per second.  Applied unless ``ZENOH_RUNTIME`` is set."""


def make_config(
    mode: str | None = MODE_CLIENT,
    connect: Sequence[str] = (),
    listen: Sequence[str] = (),
    config_file: str | os.PathLike[str] | None = None,
    *,
    connect_timeout_ms: int | None = None,
) -> zenoh.Config:
    """A Zenoh config with multicast scouting off.

    ``mode=None`` keeps the mode of ``config_file`` (Zenoh's default: peer).
    Without a config file or explicit endpoints, a client connects to
    :data:`DEFAULT_ENDPOINT`, a router listens there and a peer listens on an
    ephemeral loopback port; with a config file, its endpoints (or Zenoh's
    defaults) are kept unless overridden.  ``connect_timeout_ms`` lets a
    client wait for a router that is not up yet (-1: forever); Zenoh's client
    default (0) fails at once.  A relative certificate or key file named in
    ``config_file`` is read next to that file (a host's credentials bundle can
    be copied anywhere), not from the current directory as Zenoh would.
    """
    if mode is not None and mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    conf = zenoh.Config.from_file(os.fspath(config_file)) if config_file is not None else zenoh.Config()
    if config_file is not None:
        _files_next_to(conf, os.path.dirname(os.path.abspath(config_file)))
    if mode is not None:
        conf.insert_json5("mode", jsonio.dumps(mode))
    loopback_defaults = config_file is None
    if connect:
        conf.insert_json5("connect/endpoints", jsonio.dumps(list(connect)))
    elif loopback_defaults and mode == MODE_CLIENT:
        conf.insert_json5("connect/endpoints", jsonio.dumps([DEFAULT_ENDPOINT]))
    if listen:
        conf.insert_json5("listen/endpoints", jsonio.dumps(list(listen)))
    elif loopback_defaults and mode in (MODE_ROUTER, MODE_PEER):
        default = DEFAULT_ENDPOINT if mode == MODE_ROUTER else DEFAULT_PEER_LISTEN
        conf.insert_json5("listen/endpoints", jsonio.dumps([default]))
    if connect_timeout_ms is not None:
        conf.insert_json5("connect/timeout_ms", jsonio.dumps(int(connect_timeout_ms)))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if config_file is None or json.loads(conf.get_json("transport/shared_memory/enabled")) is True:
        conf.insert_json5("transport/shared_memory/enabled", "false")  # see SHARED_MEMORY_NOTE
    return conf


SHARED_MEMORY_NOTE = """Zenoh's shared memory is off in every TRUAV session: TRUAV's messages go through a
router over TCP, never through shared memory, and with it on (Zenoh's default, "lazy") each session locks
24 KiB of memory, charged to its user: under the usual 8 MiB RLIMIT_MEMLOCK the machine's ~350th session
(of every process of that user) is refused by the router ("close message (reason GENERIC) in response to
an OpenSyn"), so a swarm stopped short of 350 agents."""


def _files_next_to(conf: zenoh.Config, directory: str) -> None:
    for name in TLS_FILE_KEYS:
        value = json.loads(conf.get_json(f"transport/link/tls/{name}"))
        if isinstance(value, str) and value and not os.path.isabs(value):
            conf.insert_json5(f"transport/link/tls/{name}", jsonio.dumps(os.path.join(directory, value)))


def apply_creds(args: Any, identity: str) -> None:
    """With ``--creds DIR``: point ``args.config`` at ``identity``'s zenoh config in DIR.

    ``truav.bus.security.CredentialsError`` (a ValueError) if DIR is not a
    credentials directory, was made for another ``--run``, or has nothing for
    ``identity``."""
    creds_dir = getattr(args, "creds", None)
    if not creds_dir:
        return
    if getattr(args, "config", None):
        raise CredentialsError("pass either --creds or -c/--config, not both")
    run = getattr(args, "run", None)
    creds = load_credentials(creds_dir, run if isinstance(run, str) else None)
    args.config = str(creds.config_file(identity))


def apply_replay_creds(args: Any, identity: str) -> None:
    """:func:`apply_creds` for a replay (``replay``) and its operator (``supervisor``): under ``--creds`` a
    replay may publish only into its own run, ``<run>-replay`` (:func:`truav.bus.acl.replay_run`), so
    ``args.run`` becomes that run when it is None or the live run; another run is a CredentialsError."""
    creds_dir = getattr(args, "creds", None)
    if not creds_dir:
        return
    if getattr(args, "config", None):
        raise CredentialsError("pass either --creds or -c/--config, not both")
    creds = load_credentials(creds_dir)
    target = replay_run(creds.run)
    if args.run not in (None, creds.run, target):
        raise CredentialsError(f"--run {args.run!r}: with --creds {creds_dir} (made for run {creds.run!r}) a replay "
                               f"publishes into {target!r}")
    args.run = target
    args.config = str(creds.config_file(identity))


def config_from_args(args: Any) -> zenoh.Config:
    """The config for the flags of ``truav.cli.args.add_transport_args``."""
    mode = args.mode if args.mode is not None else (None if args.config else MODE_CLIENT)
    return make_config(mode, args.connect or (), args.listen or (), args.config)


def open_session(config: zenoh.Config) -> zenoh.Session:
    # Zenoh reads ZENOH_RUNTIME when a process opens its first session; child processes inherit it.
    os.environ.setdefault(ZENOH_RUNTIME_ENV, LEAN_ZENOH_RUNTIME)
    return zenoh.open(config)


def close_session(session: zenoh.Session, what: str) -> bool:
    """Close ``session``; False, logged, when Zenoh's close gives up.

    zenoh 1.x raises ``ZError("close operation timed out")`` when its teardown cannot finish in time (a
    loaded machine, links losing packets: eclipse-zenoh/zenoh#2675). The process was stopping anyway and
    its links go with it, so that is a warning, not a failure of what the process did before."""
    try:
        session.close()
        return True
    except zenoh.ZError as exc:
        logging.getLogger("truav.bus").warning("%s: Zenoh's close did not finish (%s); its links end with "
                                               "the process", what, exc)
        return False

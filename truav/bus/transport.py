"""The one place TRUAV processes touch Zenoh.

* :func:`make_config` / :func:`add_transport_args` / :func:`config_from_args`
  build a ``zenoh.Config`` with multicast scouting always off; defaults are
  loopback-only (clients connect to, and the router listens on,
  :data:`DEFAULT_ENDPOINT`).
* :class:`Bus` wraps one Zenoh session for one sender identity (``world``,
  ``uav/<i>``, ``recorder`` ...): it stamps and encodes outgoing messages with
  :mod:`truav.bus.schema`, decodes incoming ones, drops (and counts, and logs once
  per reason) anything malformed, applies a fault-injection :class:`LinkFilter`
  on the receive side, and wraps liveliness tokens.  Beacons and positions are
  sent with congestion control DROP, everything else with BLOCK.
* :func:`run_router` runs an in-process Zenoh router (zenoh-python 1.x can
  open a session in ``router`` mode) for ``truav-swarm router``.

Thread model.  Every data subscription queues its samples in a bounded
channel inside Zenoh (Rust) and has one Python thread of the Bus, its pump,
that takes them out in batches: it blocks in ``recv`` (GIL released) only
while the channel is empty and otherwise pulls with ``try_recv`` without
giving up the GIL per sample.  (zenoh-python's own callback thread releases
and re-takes the GIL for every sample, and its full FIFO blocks the whole
session's receive thread, so a flood on one key can hold up every other.)  The
channel is a FIFO by default (nothing lost; a reader that falls behind pushes
back on Zenoh) or, with :attr:`Bus.receive_ring` (real-time processes), a ring
that drops the oldest samples in Zenoh without touching Python when the
reader falls behind: a flood then costs a process at most what its pump can
take, and a message waits behind at most that many others.  An idle pump
wakes every 100 ms (zenoh-python's ``Handler.recv`` checks for signals):
measured ~19 us of CPU each, ~0.2 ms a second per subscription.  The Bus
decodes, filters and delivers a message on the pump thread, under one delivery
lock per Bus, so one Bus never runs two user callbacks at once and user
callbacks may call ``Bus.publish`` (they are not on a Zenoh network thread).
Only messages the link filter delays, and liveliness changes, go through
the Bus's scheduler thread (a heap by due time, under the same lock), so
emulated link delays cost no extra threads.  Delivering in place rather than
handing every message to the scheduler saves a thread switch per message:
measured with ``bench/bench_swarm.py`` that switch was about half of an
agent's receive cost on a 2-core VM.  A slow callback delays every later
delivery of that Bus; delayed deliveries are capped at ``max_pending``
(overflow is counted).  An :meth:`Bus.inbox` skips the callback altogether:
arrival is a timestamp and an append, and its reader decodes on its own
thread (:mod:`truav.bus.inbox`).
"""

from __future__ import annotations

import argparse
import functools
import heapq
import itertools
import json
import logging
import math
import os
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import zenoh

from truav.bus import keys, schema
from truav.bus.guard import R_REPLAYED, Guard, Rejections
from truav.bus.inbox import DEFAULT_INBOX_CAPACITY, Inbox
from truav.bus.schema import Message, SchemaError

log = logging.getLogger(__name__)

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
DEFAULT_PEER_LISTEN = "tcp/127.0.0.1:0"
MODE_CLIENT = "client"
MODE_PEER = "peer"
MODE_ROUTER = "router"
MODES = (MODE_CLIENT, MODE_PEER, MODE_ROUTER)

DEFAULT_MAX_PENDING = 100_000
DEFAULT_RECEIVE_FIFO = 256
"""Samples a FIFO subscription holds in Zenoh before it pushes back (zenoh-python's own default)."""
REALTIME_RECEIVE_RING = 256
"""Samples a real-time process's subscription holds in Zenoh before the oldest are dropped (Bus.receive_ring):
far more than a tick brings (an observation, a tick, one action or beacon per UAV), few enough that a flood
cannot make a message wait behind more than this many others."""
PUMP_BATCH = 64
PUMP_BACKOFF_S = 0.02
"""A ring subscription's pump that refused (or, into a full inbox, evicted for) more than half of its last
PUMP_BATCH samples (a flood) pauses this long: the ring then drops the flood inside Zenoh, so junk costs a
process a bounded share of a core (64 samples per pause, some 5%) whatever its rate, and a valid message
behind it waits at most this much longer. (The count is per Bus: a flood on one key can pause another.)"""
MAX_LOG_ONCE_TAGS = 1024  # distinct "log once" tags remembered; tags can hold sender-chosen keys
REPLAY_TAG = b"truav-replay"
"""Zenoh attachment on every put of a ``replay`` Bus: receivers drop it unless they accept replays."""
MAX_CACHED_PUBLISHERS = 4096
DEFAULT_ALIVE_TIMEOUT_S = 1.0
ALIVE_EMPTY_RETRY_S = (0.005, 0.01, 0.02, 0.05, 0.1)  # pauses before re-asking an empty liveliness query
CLOSE_JOIN_TIMEOUT_S = 2.0
ROUTER_POLL_S = 0.5
UNKNOWN_SRC = "?"

# Drop reasons added by the Bus on top of the schema's R_* reasons.
R_KEY_MISMATCH = "key_mismatch"  # payload does not belong on that key (kind, uav id, src)

_WILDCARD_CHARS = frozenset("*$?#")

# Kinds where the freshest value wins and loss is tolerable: published with
# CongestionControl.DROP.  Everything else (tick, obs, action, metrics, fault,
# control, and unknown keys) uses BLOCK, so a full queue delays rather than
# silently drops it.  Zenoh's default is DROP, which under CPU load drops even
# small messages queued behind a large one (seen in tests with 1 MiB payloads).
DROPPABLE_KINDS = frozenset({schema.KIND_BEACON, schema.KIND_POSITIONS})

ZENOH_RUNTIME_ENV = "ZENOH_RUNTIME"
LEAN_ZENOH_RUNTIME = "(rx: (worker_threads: 1))"
"""Zenoh's receive runtime with one worker thread instead of two.  A swarm on a
few cores runs 20+ processes; with two rx workers each message also wakes the
second one.  Measured with ``bench/bench_swarm.py`` (20 agents, 2 cores): 35k
-> 26k context switches per second.  Applied unless ``ZENOH_RUNTIME`` is set."""

DataCallback = Callable[[str, Message, bytes, int], None]  # (key, msg, raw, recv_time_ns)
RawCallback = Callable[[str, bytes, int], None]  # (key, raw, recv_time_ns)
KeyCallback = Callable[[str], None]  # liveliness: (token key)


# --- configuration -----------------------------------------------------------------
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
        conf.insert_json5("mode", json.dumps(mode))
    loopback_defaults = config_file is None
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    elif loopback_defaults and mode == MODE_CLIENT:
        conf.insert_json5("connect/endpoints", json.dumps([DEFAULT_ENDPOINT]))
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    elif loopback_defaults and mode in (MODE_ROUTER, MODE_PEER):
        default = DEFAULT_ENDPOINT if mode == MODE_ROUTER else DEFAULT_PEER_LISTEN
        conf.insert_json5("listen/endpoints", json.dumps([default]))
    if connect_timeout_ms is not None:
        conf.insert_json5("connect/timeout_ms", json.dumps(int(connect_timeout_ms)))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return conf


def _files_next_to(conf: zenoh.Config, directory: str) -> None:
    from truav.bus.security import TLS_FILE_KEYS
    for name in TLS_FILE_KEYS:
        value = json.loads(conf.get_json(f"transport/link/tls/{name}"))
        if isinstance(value, str) and value and not os.path.isabs(value):
            conf.insert_json5(f"transport/link/tls/{name}", json.dumps(os.path.join(directory, value)))


def add_transport_args(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the zenoh-example style flags ``-e/--connect``, ``-l/--listen``, ``-c/--config``, ``-m/--mode``."""
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


def apply_creds(args: argparse.Namespace, identity: str) -> None:
    """With ``--creds DIR``: point ``args.config`` at ``identity``'s zenoh config in DIR.

    ``truav.bus.security.CredentialsError`` (a ValueError) if DIR is not a
    credentials directory, was made for another ``--run``, or has nothing for
    ``identity``."""
    creds_dir = getattr(args, "creds", None)
    if not creds_dir:
        return
    from truav.bus import security
    if getattr(args, "config", None):
        raise security.CredentialsError("pass either --creds or -c/--config, not both")
    run = getattr(args, "run", None)
    creds = security.load(creds_dir, run if isinstance(run, str) else None)
    args.config = str(creds.config_file(identity))


def config_from_args(args: argparse.Namespace) -> zenoh.Config:
    """The config for the flags of :func:`add_transport_args`."""
    mode = args.mode if args.mode is not None else (None if args.config else MODE_CLIENT)
    return make_config(mode, args.connect or (), args.listen or (), args.config)


# --- link filter (fault-injection hook) ----------------------------------------------
class LinkFilter(Protocol):
    """Decides the fate of each incoming message on the receiving Bus.

    Called one message at a time (under the Bus's filter lock), once per message, with
    ``dst`` = the Bus identity and ``now_ns`` = arrival time (Bus clock).
    ``src`` is the sender id, or :data:`UNKNOWN_SRC` for unreadable raw
    payloads.  Returns ``(deliver, delay_s)``.

    A filter may also have a ``passes_everything`` attribute: while it is
    true the Bus's inboxes skip the filter (their arrival path stays a
    timestamp and an append).
    """

    def decide(self, key: str, src: str, dst: str, now_ns: int) -> tuple[bool, float]: ...


class PassThrough:
    """The default link filter: deliver everything now."""

    passes_everything = True

    def decide(self, key: str, src: str, dst: str, now_ns: int) -> tuple[bool, float]:
        return True, 0.0


@dataclass(frozen=True)
class BusStats:
    """A snapshot of a Bus's receive-side counters."""

    received: int = 0  # samples that reached this Bus (data + raw subscriptions + inboxes)
    delivered: int = 0  # user callbacks that returned normally (data, raw, liveliness) + valid messages drained
    filtered: int = 0  # dropped by the link filter
    delayed: int = 0  # delayed by the link filter
    malformed: dict[str, int] = field(default_factory=dict)  # dropped, by reason
    callback_errors: int = 0
    filter_errors: int = 0
    overflow: int = 0  # dropped because max_pending deliveries were queued, or evicted from a full inbox
    backoffs: int = 0  # pauses of a ring subscription's pump under a flood of refused messages (Bus.receive_ring)
    rejected: dict[str, dict[str, int]] = field(default_factory=dict)  # {reason: {sender: n}}, bounded senders
    sent: dict[str, int] = field(default_factory=dict)  # messages this Bus put with publish(), by kind

    @property
    def dropped_malformed(self) -> int:
        return sum(self.malformed.values())


class Handle:
    """Something declared on a Bus (subscription, token); ``close()`` undeclares it."""

    def __init__(self, what: str, undeclare: Callable[[], None]) -> None:
        self.what = what
        self._undeclare: Callable[[], None] | None = undeclare

    @property
    def closed(self) -> bool:
        return self._undeclare is None

    def close(self) -> None:
        undeclare, self._undeclare = self._undeclare, None
        if undeclare is not None:
            try:
                undeclare()
            except zenoh.ZError as exc:  # session already closed: nothing left to undeclare
                log.debug("undeclaring %s: %s", self.what, exc)

    def __repr__(self) -> str:
        return f"Handle({self.what!r}, closed={self.closed})"


class _Scheduler:
    """One thread running zero-argument jobs in due-time order (FIFO among equals)."""

    def __init__(self, name: str, max_pending: int) -> None:
        self._heap: list[tuple[int, int, Callable[[], None]]] = []
        self._counter = itertools.count()
        self._cond = threading.Condition()
        self._max_pending = max_pending
        self._running = True
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    def submit(self, due_mono_ns: int, job: Callable[[], None]) -> bool:
        """Queue ``job``; False if stopped or full."""
        with self._cond:
            if not self._running or len(self._heap) >= self._max_pending:
                return False
            heapq.heappush(self._heap, (due_mono_ns, next(self._counter), job))
            self._cond.notify()
            return True

    def in_thread(self) -> bool:
        return threading.current_thread() is self._thread

    def _loop(self) -> None:
        while True:
            with self._cond:
                while self._running:
                    if not self._heap:
                        self._cond.wait()
                        continue
                    wait_ns = self._heap[0][0] - time.monotonic_ns()
                    if wait_ns <= 0:
                        break
                    self._cond.wait(wait_ns / 1e9)
                if not self._running:
                    return
                _, _, job = heapq.heappop(self._heap)
            try:
                job()
            except Exception:  # jobs guard user code themselves; this is a last resort
                log.exception("bus delivery job failed")

    def stop(self) -> None:
        with self._cond:
            self._running = False
            self._heap.clear()
            self._cond.notify_all()
        if not self.in_thread():
            self._thread.join(CLOSE_JOIN_TIMEOUT_S)


# --- pull receiver -------------------------------------------------------------------
DEFAULT_PULL_CAPACITY = 65_536
PULL_IDLE_SLEEP_S = 0.001


class RawReceiver:
    """Pulls (key, payload, recv_time_ns) from a FIFO subscriber; one consumer thread only."""

    def __init__(self, sub: zenoh.Subscriber, bus: "Bus") -> None:
        self._sub, self._bus = sub, bus

    def try_recv(self) -> tuple[str, bytes, int] | None:
        """The next sample, or None if none is waiting. Its receive time is when it is pulled."""
        while True:
            sample = self._sub.try_recv()
            while sample is not None and sample.kind != zenoh.SampleKind.PUT:
                sample = self._sub.try_recv()
            if sample is None:
                return None
            key = str(sample.key_expr)
            # Not even a recorder keeps a payload too large for its key's kind: checked before copying.
            limit = _size_limit_of_key(key)
            if len(sample.payload) > limit:
                self._bus._count_received(1, delivered=0)
                self._bus._count_malformed(key, SchemaError(schema.R_TOO_LARGE, f"{len(sample.payload)} bytes, "
                                                            f"limit {limit}", src=None))
                continue
            self._bus._count_received(1)
            return key, sample.payload.to_bytes(), self._bus._clock()

    def recv(self, timeout: float) -> tuple[str, bytes, int] | None:
        """The next sample, waiting up to ``timeout`` seconds (polling at 1 ms)."""
        deadline = time.monotonic() + timeout
        while True:
            item = self.try_recv()
            if item is not None or time.monotonic() >= deadline:
                return item
            time.sleep(PULL_IDLE_SLEEP_S)


# --- the bus -------------------------------------------------------------------------
class Bus:
    """A Zenoh session owned by one sender identity; a context manager.

    ``identity`` is the ``src`` stamped on every message (``world``,
    ``uav/<i>``, ``recorder``, ``fault``, ``replay``); ``run`` scopes the keys
    it may publish.  An agent ``uav/<i>`` may only publish under
    ``truav/<run>/uav/<i>/`` and declare ``truav/<run>/alive/uav/<i>``;
    everyone else anywhere under ``truav/<run>/``.
    """

    def __init__(
        self,
        identity: str,
        run: str,
        config: zenoh.Config | None = None,
        *,
        link_filter: LinkFilter | None = None,
        clock: Callable[[], int] = time.time_ns,
        max_pending: int = DEFAULT_MAX_PENDING,
    ) -> None:
        self._run = keys.validate_run(run)
        self._seq = schema.Sequencer(identity, clock)
        self._identity = self._seq.src
        self._uav = keys.parse_uav_identity(self._identity)
        if self._identity.startswith("uav/") and self._uav is None:
            raise ValueError(f"identity {identity!r}: UAV identities are uav/<id> with id in [0, {keys.MAX_UAVS})")
        self._prefix = keys.prefix(run) + "/"
        self._filter: LinkFilter = link_filter if link_filter is not None else PassThrough()
        self._clock = clock
        self._lock = threading.Lock()
        self._deliver_lock = threading.RLock()  # one user callback at a time, whichever thread delivers
        self._filter_lock = threading.Lock()  # the link filter sees one message at a time (inboxes decide off that lock)
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._sent: dict[str, int] = {}  # kind -> messages published (this incarnation's, see stats())
        self._handles: list[Handle] = []
        self._pumps: list[threading.Thread] = []
        self._logged: set[str] = set()
        self._received = self._delivered = self._filtered = self._delayed = 0
        self._callback_errors = self._filter_errors = self._overflow = self._backoffs = 0
        self._malformed: dict[str, int] = {}
        self._shed = 0  # messages refused or evicted so far (read without the lock by the pumps)
        self.rejections = Rejections(f"bus {self._identity}", logger=log)
        """Every message this Bus refused, by reason and sender (schema, placement, guard, replay tag)."""
        self.guard: Guard | None = None
        """Sender/range checks applied after the schema (:mod:`truav.bus.guard`); None: schema only."""
        self.accept_replay = True
        """Deliver puts tagged by a ``replay`` Bus; the live run's world and agents set it False
        (such puts are then dropped and counted)."""
        self.receive_ring: int | None = None
        """None: subscriptions declared from now on queue in a FIFO in Zenoh (nothing is lost; a reader
        that falls behind pushes back on Zenoh's queues). N: a ring of N samples each, the oldest dropped
        inside Zenoh, without Python, when the reader falls behind (real time: the newest value matters,
        and a flood costs at most what the reader takes; :data:`REALTIME_RECEIVE_RING`)."""
        self._tag = REPLAY_TAG if self._identity == keys.SRC_REPLAY else None
        self._closed = False
        self._session = _open_session(config if config is not None else make_config())
        self._sched = _Scheduler(f"truav-bus[{self._identity}]", max_pending)

    # -- properties / lifecycle --
    @property
    def identity(self) -> str:
        return self._identity

    @property
    def incarnation(self) -> int:
        """The ``inc`` this Bus stamps on what it publishes (one per Bus: a process lifetime)."""
        return self._seq.incarnation

    @property
    def run(self) -> str:
        return self._run

    @property
    def session(self) -> zenoh.Session:
        """The underlying session (escape hatch; prefer the Bus methods)."""
        return self._session

    @property
    def link_filter(self) -> LinkFilter:
        return self._filter

    @link_filter.setter
    def link_filter(self, value: LinkFilter | None) -> None:
        self._filter = value if value is not None else PassThrough()

    @property
    def closed(self) -> bool:
        return self._closed

    def __enter__(self) -> Bus:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Undeclare everything, close the session and stop the delivery thread. Idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            handles, self._handles = self._handles, []
            publishers, self._publishers = list(self._publishers.values()), {}
        for h in handles:
            h.close()
        for p in publishers:
            try:
                p.undeclare()
            except zenoh.ZError:
                pass
            except RuntimeError as exc:  # "Already borrowed": another thread is inside this publisher's put
                log.debug("bus %s: publisher busy at close (%s); the session's close undeclares it",
                          self._identity, exc)
        self._session.close()
        self._sched.stop()
        # A pump still waiting inside Zenoh when the interpreter exits would be torn down mid-Rust-call
        # (a daemon thread re-taking the GIL during finalization): the process aborts ("FATAL: exception
        # not rethrown"). Closing the session ends their waits; wait for them to return.
        deadline = time.monotonic() + CLOSE_JOIN_TIMEOUT_S
        for pump in self._pumps:
            if pump is not threading.current_thread():
                pump.join(max(deadline - time.monotonic(), 0.0))

    def stats(self) -> BusStats:
        with self._lock:
            return BusStats(
                received=self._received,
                delivered=self._delivered,
                filtered=self._filtered,
                delayed=self._delayed,
                malformed=dict(self._malformed),
                callback_errors=self._callback_errors,
                filter_errors=self._filter_errors,
                overflow=self._overflow,
                backoffs=self._backoffs,
                rejected=self.rejections.as_dict(),
                sent=dict(self._sent),
            )

    @property
    def dropped_malformed(self) -> dict[str, int]:
        """Malformed messages dropped so far, by reason."""
        with self._lock:
            return dict(self._malformed)

    # -- publishing --
    def check_publish(self, key: str) -> str:
        """Return ``key`` if this identity may publish (or declare a token) on it.

        ValueError for a non-concrete key; PermissionError outside this run or,
        for ``uav/<i>``, outside ``uav/<i>/`` and ``alive/uav/<i>``.
        """
        if not isinstance(key, str) or not key or _WILDCARD_CHARS.intersection(key) or "//" in key:
            raise ValueError(f"cannot publish on {key!r}: need a concrete key without wildcards")
        if not key.startswith(self._prefix):
            raise PermissionError(f"{self._identity} may not publish on {key!r}: outside {self._prefix}")
        if self._uav is not None:
            own = keys.uav_prefix(self._run, self._uav) + "/"
            if not key.startswith(own) and key != keys.alive_uav(self._run, self._uav):
                raise PermissionError(
                    f"{self._identity} may only publish under {own} and {keys.alive_uav(self._run, self._uav)}, "
                    f"not on {key!r}"
                )
        return key

    def publish(self, key: str, msg: Message, pad_to: int | None = None) -> Message:
        """Stamp ``msg`` (src=identity, next seq, t=clock), encode and put it; return the stamped message.

        ``pad_to``: a message with a ``pad`` field (state, command) is padded to that many bytes
        once stamped (:func:`truav.bus.schema.padded`). PermissionError/ValueError from
        :meth:`check_publish`; SchemaError if ``msg`` does not belong on ``key`` (receivers would drop it).
        """
        self.check_publish(key)
        stamped = self._seq.stamp(msg)
        if pad_to is not None:
            stamped = schema.padded(stamped, pad_to)
        _check_placement(key, stamped)
        self._put(key, schema.encode(stamped))
        with self._lock:  # counted once handed to Zenoh: what a receiver could have got
            self._sent[stamped.KIND] = self._sent.get(stamped.KIND, 0) + 1
        if self.guard is not None:
            self.guard.sent(stamped)
        return stamped

    def prepare(self, *keys_: str) -> None:
        """Declare the publishers of ``keys_`` now, so a process's first message on each is not
        slowed by the declaration (a round trip to the router, seen as a latency spike at tick 0)."""
        for key in keys_:
            self._publisher(self.check_publish(key))

    def await_subscribers(self, key: str, timeout: float) -> bool:
        """Wait until someone subscribes to ``key`` (at most ``timeout`` s); whether anyone does.

        A one-shot sender (`truav-swarm down`) needs it: a freshly declared publisher drops
        what it puts until its router has told it of a matching subscriber, which over
        linked routers takes longer than opening the session."""
        pub = self._publisher(self.check_publish(key))
        deadline = time.monotonic() + timeout
        while pub is not None and not pub.matching_status.matching:
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.02)
        return True

    def publish_raw(self, key: str, data: bytes) -> None:
        """Put pre-encoded bytes as they are (replay, tests); same permission check, no validation."""
        self._put(self.check_publish(key), bytes(data))

    def _publisher(self, key: str) -> zenoh.Publisher | None:
        """The cached publisher of ``key``, declared on first use (None once the cache is full)."""
        with self._lock:
            if self._closed:
                raise RuntimeError(f"bus {self._identity} is closed")
            pub = self._publishers.get(key)
            if pub is None and len(self._publishers) < MAX_CACHED_PUBLISHERS:
                pub = self._publishers[key] = self._session.declare_publisher(
                    key, congestion_control=congestion_control(key))
            return pub

    def _put(self, key: str, data: bytes) -> None:
        pub = self._publisher(key)
        try:
            if pub is not None:
                pub.put(data, attachment=self._tag)
            else:
                self._session.put(key, data, congestion_control=congestion_control(key), attachment=self._tag)
        except zenoh.ZError:
            if self._closed:  # close() ran between the check and the put: the same error as putting after it
                raise RuntimeError(f"bus {self._identity} is closed") from None
            raise

    def _refuse_replayed(self, key: str, sample: zenoh.Sample) -> bool:
        """True (counted) if ``sample`` was put by a replay and this Bus does not accept replays."""
        att = sample.attachment
        if att is None or self.accept_replay or att.to_bytes() != REPLAY_TAG:
            return False
        self._count_malformed(key, SchemaError(R_REPLAYED, "replayed traffic in a live run (accept_replay is off)",
                                               src=keys.SRC_REPLAY))
        return True

    # -- subscribing --
    def subscribe(self, key_expr: str, callback: DataCallback) -> Handle:
        """Deliver decoded, valid messages on ``key_expr`` as ``callback(key, msg, raw, recv_time_ns)``.

        Malformed payloads and payloads that do not belong on their key are
        dropped, counted by reason and logged once per reason.  ``recv_time_ns``
        is the Bus clock when the message arrived from Zenoh, or at delivery
        for a message the link filter delayed.
        """
        return self._declare_data(key_expr, lambda key, raw, arr_ns, arr_mono: self._on_data(
            key, raw, arr_ns, arr_mono, callback), max_bytes=schema.MAX_PAYLOAD_BYTES)

    def subscribe_raw(self, key_expr: str, callback: RawCallback) -> Handle:
        """Deliver every payload on ``key_expr`` undecoded as ``callback(key, raw, recv_time_ns)`` (recorder).

        The link filter still applies, with the sender read from the envelope
        when possible (:data:`UNKNOWN_SRC` otherwise).
        """
        return self._declare_data(key_expr, lambda key, raw, arr_ns, arr_mono: self._on_raw(
            key, raw, arr_ns, arr_mono, callback))

    def receive_raw(self, key_expr: str, capacity: int = DEFAULT_PULL_CAPACITY) -> "RawReceiver":
        """A pull receiver of raw payloads on ``key_expr`` (the recorder's fast path).

        Samples queue in a bounded Zenoh FIFO and are pulled by one consumer
        thread: no Python callback or delivery thread per message. When the
        consumer lags, the full FIFO pushes back on Zenoh's own queues
        (BLOCK publishers slow down, DROP ones drop at the source), so nothing
        is dropped silently in this process. No link filter applies (a
        recorder records what the bus carried); refused when one is set.
        """
        if not isinstance(self._filter, PassThrough):
            raise ValueError("receive_raw records what the bus carried: not available with a link filter")
        sub = self._session.declare_subscriber(key_expr, zenoh.handlers.FifoChannel(capacity))
        receiver = RawReceiver(sub, self)
        self._register(Handle(f"pull subscriber {key_expr}", sub.undeclare))
        return receiver

    def inbox(self, key_expr: str, capacity: int = DEFAULT_INBOX_CAPACITY, compact: bool = True) -> Inbox:
        """An :class:`~truav.bus.inbox.Inbox` of valid messages on ``key_expr``, decoded when drained.

        For traffic a process reads once per cycle (an agent's neighbour
        beacons): arrival costs a timestamp and an append, not a callback.
        The link filter applies at arrival, as for :meth:`subscribe`. ``compact``: see
        :class:`~truav.bus.inbox.Inbox`.
        """
        box = Inbox(self, capacity, compact=compact)
        self.feed(box, key_expr)
        return box

    def feed(self, box: Inbox, key_expr: str) -> Handle:  # box: anything with Inbox.on_sample
        """Also put what arrives on ``key_expr`` into ``box`` (an agent's range-limited beacon cells
        come and go as it moves); ``close()`` the returned handle to stop."""
        return self._pump(key_expr, box.on_sample, f"inbox {key_expr}")

    def _count_received(self, n: int, delivered: int | None = None) -> None:
        with self._lock:
            self._received += n
            self._delivered += n if delivered is None else delivered

    def _declare_data(
        self, key_expr: str, handle: Callable[[str, bytes, int, int], None], max_bytes: int | None = None
    ) -> Handle:
        def on_sample(sample: zenoh.Sample) -> None:  # zenoh-python's callback thread: keep it short
            if sample.kind != zenoh.SampleKind.PUT:
                return
            arrival_ns, arrival_mono = self._clock(), time.monotonic_ns()
            key = str(sample.key_expr)
            with self._lock:
                self._received += 1
            if self._refuse_replayed(key, sample):
                return
            raw = self._payload(key, sample, max_bytes)
            if raw is None or self._closed:
                return
            with self._deliver_lock:  # one message at a time through filter and callback
                handle(key, raw, arrival_ns, arrival_mono)

        return self._pump(key_expr, on_sample, f"subscriber {key_expr}")

    def _pump(self, key_expr: str, on_sample: Callable[[zenoh.Sample], None], what: str) -> Handle:
        """Subscribe ``key_expr`` into a bounded Zenoh channel (FIFO, or a ring with :attr:`receive_ring`)
        and start its pump thread, which hands each sample to ``on_sample`` (see the module docstring)."""
        ring = self.receive_ring
        handler = zenoh.handlers.RingChannel(ring) if ring else zenoh.handlers.FifoChannel(DEFAULT_RECEIVE_FIFO)
        sub = self._session.declare_subscriber(key_expr, handler)
        handle = self._register(Handle(what, sub.undeclare))
        # The pump reads the handler, not the subscriber: a thread blocked in Subscriber.recv holds a borrow
        # of it that makes undeclare fail ("Already borrowed"); undeclaring ends the handler's recv instead.
        pump = threading.Thread(target=self._run_pump, args=(sub.handler, on_sample, what, bool(ring)), daemon=True,
                                name=f"truav-rx[{self._identity}] {key_expr}")
        with self._lock:
            self._pumps.append(pump)
        pump.start()
        return handle

    def _run_pump(self, sub: zenoh.handlers.Handler, on_sample: Callable[[zenoh.Sample], None], what: str,
                  backs_off: bool) -> None:
        while True:
            try:
                sample = sub.recv()  # waits with the GIL released
                taken, shed = 0, self._shed
                while sample is not None:
                    try:
                        on_sample(sample)
                    except Exception as exc:  # the handlers guard user code; this is a last resort
                        if self._first(f"pump:{what}:{type(exc).__name__}"):
                            log.exception("bus %s: %s failed on a sample (%r); continuing", self._identity, what, exc)
                    taken += 1
                    if taken == PUMP_BATCH:
                        if backs_off and 2 * (self._shed - shed) > PUMP_BATCH:  # a flood: let the ring drop it
                            self._count_backoff()
                            time.sleep(PUMP_BACKOFF_S)
                        taken, shed = 0, self._shed
                    sample = sub.try_recv()  # the rest of a batch without giving up the GIL per sample
            except zenoh.ZError:  # undeclared, or the session closed
                return

    def _payload(self, key: str, sample: zenoh.Sample, max_bytes: int | None) -> bytes | None:
        """The sample's bytes; None (counted as too large) above ``max_bytes``, checked before copying."""
        size = len(sample.payload)
        if max_bytes is not None:
            max_bytes = min(max_bytes, _size_limit_of_key(key))  # the key's kind says how large it may be
        if max_bytes is not None and size > max_bytes:
            self._count_malformed(key, SchemaError(schema.R_TOO_LARGE, f"{size} bytes, limit {max_bytes}"))
            return None
        return sample.payload.to_bytes()

    def _on_data(self, key: str, raw: bytes, arrival_ns: int, arrival_mono: int, callback: DataCallback) -> None:
        msg = self._decode(key, raw)
        if msg is not None:
            self._route(key, msg.src, arrival_ns, arrival_mono, lambda recv_ns: callback(key, msg, raw, recv_ns))

    def _decode(self, key: str, raw: bytes) -> Message | None:
        """The valid message ``raw`` carries on ``key``, or None (dropped, counted, logged once per reason)."""
        try:
            msg = schema.decode(raw, _key_facts(key)[0])
            _check_placement(key, msg)
            guard = self.guard
            verdict = guard.check(key, msg) if guard is not None else None
            if verdict is not None:
                raise SchemaError(verdict[0], verdict[1], src=msg.src)
        except SchemaError as exc:
            self._count_malformed(key, exc)
            return None
        return msg

    def _filters_nothing(self) -> bool:
        return getattr(self._filter, "passes_everything", False)

    def _admit(self, key: str, raw: bytes, arrival_ns: int) -> float | None:
        """The link filter's verdict on a raw message (see :meth:`_decide`), for an inbox."""
        return self._decide(key, schema.peek_src(raw) or UNKNOWN_SRC, arrival_ns)

    def _on_raw(self, key: str, raw: bytes, arrival_ns: int, arrival_mono: int, callback: RawCallback) -> None:
        src = schema.peek_src(raw) or UNKNOWN_SRC
        self._route(key, src, arrival_ns, arrival_mono, lambda recv_ns: callback(key, raw, recv_ns))

    def _route(self, key: str, src: str, arrival_ns: int, arrival_mono: int, deliver: Callable[[int], None]) -> None:
        """Apply the link filter, then deliver now or schedule for later.

        ``deliver(recv_ns)`` gets the arrival time for a message delivered now
        and the delivery time for one the filter delayed."""
        delay_s = self._decide(key, src, arrival_ns)
        if delay_s is None:
            return
        if delay_s <= 0:
            self._invoke(key, lambda: deliver(arrival_ns))
            return
        job = lambda: self._invoke(key, lambda: deliver(self._clock()))  # noqa: E731
        if not self._sched.submit(arrival_mono + int(delay_s * 1e9), job):
            self._count_overflow()

    def _decide(self, key: str, src: str, arrival_ns: int) -> float | None:
        """The link filter's verdict: None to drop, else the delay in s (counted as filtered / delayed).

        A filter that raises or returns a bad delay fails open (delivered now,
        counted, logged once)."""
        try:
            with self._filter_lock:
                ok, delay_s = self._filter.decide(key, src, self._identity, arrival_ns)
            delay_s = float(delay_s)
            if not math.isfinite(delay_s) or delay_s < 0:
                raise ValueError(f"delay_s={delay_s} must be finite and >= 0")
        except Exception as exc:  # a broken filter must not silence the bus: fail open
            with self._lock:
                self._filter_errors += 1
            if self._first(f"filter:{type(exc).__name__}"):
                log.warning("link filter failed on %s from %s (%r); delivering anyway", key, src, exc)
            ok, delay_s = True, 0.0
        if not ok:
            with self._lock:
                self._filtered += 1
            return None
        if delay_s > 0:
            with self._lock:
                self._delayed += 1
        return delay_s

    def _invoke(self, key: str, deliver: Callable[[], None]) -> None:
        try:
            with self._deliver_lock:
                deliver()
        except Exception as exc:
            with self._lock:
                self._callback_errors += 1
            if self._first(f"callback:{key}:{type(exc).__name__}"):
                log.exception("bus %s: callback for %s raised %r; continuing (repeats only counted)",
                              self._identity, key, exc)
        else:
            with self._lock:
                self._delivered += 1

    def _count_malformed(self, key: str, exc: SchemaError) -> None:
        """Count a refused message by reason (``malformed``) and by reason and sender (``rejections``,
        which logs once per sender and reason)."""
        with self._lock:
            self._malformed[exc.reason] = self._malformed.get(exc.reason, 0) + 1
            self._shed += 1
        self.rejections.add(exc.reason, exc.src, key, str(exc))

    def _count_backoff(self) -> None:
        with self._lock:
            self._backoffs += 1
        if self._first("backoff"):
            log.warning("bus %s: flooded with messages it refuses; its receive rings drop the excess inside Zenoh "
                        "(pauses only counted from now on)", self._identity)

    def _count_overflow(self) -> None:
        with self._lock:
            self._overflow += 1
            self._shed += 1
        if self._first("overflow"):
            log.warning("bus %s: delivery queue full, dropping messages (only counted from now on)", self._identity)

    def _first(self, tag: str) -> bool:
        """True the first time ``tag`` is seen: the log-once-per-reason gate."""
        with self._lock:
            if tag in self._logged or len(self._logged) >= MAX_LOG_ONCE_TAGS:
                return False
            self._logged.add(tag)
            return True

    # -- liveliness --
    def declare_liveliness(self, token_key: str) -> Handle:
        """Declare a liveliness token (same permission rules as publish); it dies with the session."""
        token = self._session.liveliness().declare_token(self.check_publish(token_key))
        return self._register(Handle(f"token {token_key}", token.undeclare))

    def watch_liveliness(self, key_expr: str, on_join: KeyCallback, on_leave: KeyCallback) -> Handle:
        """Call ``on_join(key)`` / ``on_leave(key)`` as tokens on ``key_expr`` appear / vanish.

        Tokens alive at declaration are reported as joins (history).  Runs on the
        scheduler thread under the delivery lock; the link filter does not apply.
        """
        def on_sample(sample: zenoh.Sample) -> None:
            key = str(sample.key_expr)
            cb = on_join if sample.kind == zenoh.SampleKind.PUT else on_leave
            if not self._sched.submit(time.monotonic_ns(), lambda: self._invoke(key, lambda: cb(key))):
                self._count_overflow()

        sub = self._session.liveliness().declare_subscriber(key_expr, on_sample, history=True)
        return self._register(Handle(f"liveliness watch {key_expr}", sub.undeclare))

    def alive(self, key_expr: str, timeout: float = DEFAULT_ALIVE_TIMEOUT_S) -> list[str]:
        """Keys of the liveliness tokens currently alive on ``key_expr`` (blocks up to ``timeout`` s).

        A snapshot; use :meth:`watch_liveliness` to track membership.  In
        zenoh 1.10 a liveliness query sent within a few ms of another session
        joining or leaving the router can come back empty at once although
        tokens exist (longer under CPU load), so an empty answer is re-asked a
        few times (:data:`ALIVE_EMPTY_RETRY_S`, ~185 ms in all, within
        ``timeout``) before it is believed.
        """
        deadline = time.monotonic() + timeout
        found = self._query_tokens(key_expr, deadline)
        for pause in ALIVE_EMPTY_RETRY_S:
            if found or time.monotonic() + pause >= deadline:
                break
            time.sleep(pause)
            found = self._query_tokens(key_expr, deadline)
        return sorted(found)

    def _query_tokens(self, key_expr: str, deadline: float) -> set[str]:
        found = set()
        left = max(deadline - time.monotonic(), 0.0)
        for reply in self._session.liveliness().get(key_expr, timeout=left):
            sample = reply.ok
            if sample is not None:
                found.add(str(sample.key_expr))
        return found

    def _register(self, handle: Handle) -> Handle:
        with self._lock:
            if not self._closed:
                self._handles.append(handle)
                return handle
        handle.close()
        raise RuntimeError(f"bus {self._identity} is closed")


# Which message kind belongs on which key (after ``truav/<run>/``).
_KIND_BY_KEY = {
    ("world", "tick"): schema.KIND_TICK,
    ("world", "positions"): schema.KIND_POSITIONS,
    ("metrics",): schema.KIND_METRICS,
    ("fault",): schema.KIND_FAULT,
    ("control",): schema.KIND_CONTROL,
    ("uav", keys.OBS): schema.KIND_OBS,
    ("uav", keys.BEACON): schema.KIND_BEACON,
    ("uav", keys.ACTION): schema.KIND_ACTION,
    ("uav", keys.STATE): schema.KIND_STATE,
    ("uav", keys.HEALTH): schema.KIND_HEALTH,
    (keys.CONTROLLER,): schema.KIND_COMMAND,
}


def congestion_control(key: str) -> zenoh.CongestionControl:
    """DROP for keys of :data:`DROPPABLE_KINDS` (beacons, positions), BLOCK for everything else."""
    droppable = expected_kind(key) in DROPPABLE_KINDS
    return zenoh.CongestionControl.DROP if droppable else zenoh.CongestionControl.BLOCK


def expected_kind(key: str) -> str | None:
    """The message kind that belongs on a TRUAV key, or None if the key is not a known data key."""
    parts = key.split("/")
    if len(parts) < 3 or parts[0] != keys.ROOT:
        return None
    rest = parts[2:]
    if rest[0] == "uav":
        if len(rest) == 4 and rest[2] == keys.BEACON:  # a range-limited beacon under its map cell
            return schema.KIND_BEACON
        return _KIND_BY_KEY.get(("uav", rest[2])) if len(rest) == 3 else None
    if rest[0] == "world":
        return _KIND_BY_KEY.get(tuple(rest)) if len(rest) == 2 else None
    return _KIND_BY_KEY.get((rest[0],)) if len(rest) >= 2 else None


def _check_placement(key: str, msg: Message) -> None:
    """SchemaError(R_KEY_MISMATCH) if ``msg`` does not belong on ``key``.

    Checked: the kind the key carries, the body's ``uav`` against the key's
    UAV id, a ``uav/<j>`` sender only on keys of UAV ``j``, the metrics scope
    and the fault kind against the last key chunk.
    """
    kind, key_uav = _key_facts(key)
    if kind is not None and kind != msg.KIND:
        raise SchemaError(R_KEY_MISMATCH, f"{msg.KIND} message on {key} (expects {kind})", src=msg.src)
    body_uav = getattr(msg, "uav", None)
    if key_uav is not None and body_uav is not None and body_uav != key_uav:
        raise SchemaError(R_KEY_MISMATCH, f"{msg.KIND} for uav {body_uav} on {key}", src=msg.src)
    src_uav = _src_uav(msg.src)
    if src_uav is not None and src_uav != key_uav:
        raise SchemaError(R_KEY_MISMATCH, f"sender {msg.src} may not appear on {key}", src=msg.src)
    last = key.rsplit("/", 1)[-1]
    if kind == schema.KIND_METRICS and isinstance(msg, schema.Metrics) and msg.scope != last:
        raise SchemaError(R_KEY_MISMATCH, f"{msg.scope} metrics on {key}", src=msg.src)
    if kind == schema.KIND_FAULT and isinstance(msg, schema.Fault) and msg.fault != last:
        raise SchemaError(R_KEY_MISMATCH, f"{msg.fault} fault on {key}", src=msg.src)
    if kind == schema.KIND_COMMAND and isinstance(msg, schema.Command) and last != str(msg.uav):
        raise SchemaError(R_KEY_MISMATCH, f"command for uav {msg.uav} on {key}", src=msg.src)


# A process sees the same few keys and senders over and over: parse each once (bounded caches,
# so a flood of distinct keys from a misbehaving peer cannot grow memory).
@functools.lru_cache(maxsize=4096)
def _key_facts(key: str) -> tuple[str | None, int | None]:
    """(expected_kind, UAV id) of a key."""
    return expected_kind(key), keys.parse_uav_id(key)


@functools.lru_cache(maxsize=4096)
def _size_limit_of_key(key: str) -> int:
    kind = expected_kind(key)
    return schema.size_limit(kind) if kind is not None else schema.MAX_PAYLOAD_BYTES


@functools.lru_cache(maxsize=4096)
def _src_uav(src: str) -> int | None:
    return keys.parse_uav_identity(src)


def _open_session(config: zenoh.Config) -> zenoh.Session:
    # Zenoh reads ZENOH_RUNTIME when a process opens its first session; child processes inherit it.
    os.environ.setdefault(ZENOH_RUNTIME_ENV, LEAN_ZENOH_RUNTIME)
    return zenoh.open(config)


# --- router --------------------------------------------------------------------------
# Zenoh counts payload + attachment against a low-pass limit; ours carry at most a short replay tag.
ROUTER_SIZE_SLACK_BYTES = 1024


def router_size_filters() -> list[dict]:
    """Zenoh ``low_pass_filter`` items: the router drops, on ingress from any link, a put larger
    than its key's message kind may be (:func:`truav.bus.schema.size_limit`), so an oversized
    payload costs one router check instead of a copy to every subscriber."""
    by_limit: dict[int, list[str]] = {}
    for parts, kind in _KIND_BY_KEY.items():
        if parts[0] == "uav":
            expr = f"{keys.ROOT}/*/uav/*/{parts[1]}"
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
        conf.insert_json5("low_pass_filter", json.dumps(router_size_filters()))
    return _open_session(conf)


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
    with open_router(listen, connect, config_file) as session:
        log.info("zenoh router %s listening on %s", session.zid(), ", ".join(listen) or "config endpoints")
        if on_ready is not None:
            on_ready()
        try:
            while not stop.wait(ROUTER_POLL_S):
                pass
        except KeyboardInterrupt:
            log.info("router interrupted")
    log.info("zenoh router stopped")

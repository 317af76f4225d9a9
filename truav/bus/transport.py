"""The one place TRUAV processes touch Zenoh.

* :class:`Bus` wraps one Zenoh session for one sender identity (``world``,
  ``uav/<i>``, ``recorder`` ...): it stamps and encodes outgoing messages with
  :mod:`truav.wire.schema`, decodes incoming ones, drops (and counts, and logs once
  per reason) anything malformed, applies a fault-injection :class:`LinkFilter`
  on the receive side, and wraps liveliness tokens.  Beacons and positions are
  sent with congestion control DROP, everything else with BLOCK.  Its parts:
  :mod:`truav.bus.publishing`, :mod:`truav.bus.receiving`, :mod:`truav.bus.delivery`
  and :mod:`truav.bus.liveliness` (mixins), :mod:`truav.bus.scheduler`,
  :mod:`truav.bus.bus_types`.
* :mod:`truav.bus.zenoh_config` builds a ``zenoh.Config`` with multicast scouting
  always off (:func:`make_config`; defaults are loopback-only: clients connect to,
  and the router listens on, :data:`DEFAULT_ENDPOINT`); the command-line flags are
  ``truav.cli.args.add_transport_args``.
* :mod:`truav.bus.placement` says which kind belongs on which key;
  :mod:`truav.bus.router` runs an in-process Zenoh router (zenoh-python 1.x can
  open a session in ``router`` mode) for ``truav-swarm router``.

Every name these modules export that callers took from here is re-exported here.

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

import logging
import threading
import time
from collections.abc import Callable

import zenoh

from truav.wire import keys, schema
from truav.bus.bus_types import (  # noqa: F401  (re-exported)
    CLOSE_JOIN_TIMEOUT_S, UNKNOWN_SRC, BusStats, DataCallback, Handle, KeyCallback, LinkFilter, PassThrough,
    RawCallback)
from truav.bus.delivery import MAX_LOG_ONCE_TAGS, Delivery  # noqa: F401
from truav.bus.liveliness import ALIVE_EMPTY_RETRY_S, DEFAULT_ALIVE_TIMEOUT_S, Liveliness  # noqa: F401
from truav.bus.queries import Queries, QueryRefused  # noqa: F401
from truav.wire.guard import Guard, Rejections
from truav.bus.placement import (  # noqa: F401
    DROPPABLE_KINDS, R_KEY_MISMATCH, check_placement, congestion_control, expected_kind)
from truav.bus.publishing import MAX_CACHED_PUBLISHERS, REPLAY_TAG, Publishing  # noqa: F401
from truav.bus.receiving import (  # noqa: F401
    DEFAULT_PULL_CAPACITY, DEFAULT_RECEIVE_FIFO, PUMP_BACKOFF_S, PUMP_BATCH, REALTIME_RECEIVE_RING, RawReceiver,
    Receiving)
from truav.bus.router import ROUTER_SIZE_SLACK_BYTES, open_router, router_size_filters, run_router  # noqa: F401
from truav.bus.scheduler import Scheduler
from truav.bus.zenoh_config import (  # noqa: F401
    DEFAULT_ENDPOINT, DEFAULT_PEER_LISTEN, LEAN_ZENOH_RUNTIME, MODE_CLIENT, MODE_PEER, MODE_ROUTER, MODES,
    ZENOH_RUNTIME_ENV, apply_creds, close_session, config_from_args, make_config, open_session)

log = logging.getLogger(__name__)

DEFAULT_MAX_PENDING = 100_000


class Bus(Publishing, Receiving, Delivery, Liveliness, Queries):
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
        self.on_refused: Callable[[str, schema.SchemaError], None] | None = None
        """Called with (key, error) for every message this Bus refuses (after counting it): the world tells
        the sender (truav.wire.rejection_notices). Keep it short: it runs on the receive path."""
        self.guard: Guard | None = None
        """Sender/range checks applied after the schema (:mod:`truav.wire.guard`); None: schema only."""
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
        self._session = open_session(config if config is not None else make_config())
        self._sched = Scheduler(f"truav-bus[{self._identity}]", max_pending)

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
        close_session(self._session, f"bus {self._identity}")  # a timed-out close must not skip what follows
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

    def _register(self, handle: Handle) -> Handle:
        with self._lock:
            if not self._closed:
                self._handles.append(handle)
                return handle
        handle.close()
        raise RuntimeError(f"bus {self._identity} is closed")

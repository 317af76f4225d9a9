"""One beacon subscription for every agent a process hosts (``--share-beacons``), decoded once.

Each beacon then crosses Zenoh once per process, and is decoded and schema-checked once per process
(schema, placement, replay tag, size, the guard's sender and range rules) instead of once per hosted
agent: at 100 agents in lock-step, 20 per process, 100 decodes per process and tick instead of 2,000.
Every hosted agent still gets it through what belongs to it alone, counted on its own bus as before
(received, delivered, filtered, delayed, malformed and rejected by reason and sender):

* its replay rule (``accept_replay``) and its link filter (the fault model per receiving UAV link:
  drop, delay, partition by (src, receiver)), decided before decoding as an inbox does, with the same
  sender read from the envelope;
* its own guard's tick window (the only part of the guard that differs between the agents of one
  process); a beacon outside it, or one the shared check refused, is checked by that agent's own
  guard, so the reason and detail it counts are the ones it counted before.

A batch of beacons (:class:`truav.wire.schema.Beacons`, ``--batch-beacons``) is split into its
entries here, each then checked, filtered per link and counted as a beacon its UAV sent alone on
its own key (:func:`split_batch`).

Arrival (Zenoh's pump thread) is an append; the first hosted agent that takes its beacons decodes
what arrived for all of them (:meth:`SharedBeacons.process`), and every agent's view then holds the
same decoded messages by reference (no per-agent copy while no link filter applies).
"""

from __future__ import annotations

import functools
import heapq
import itertools
import threading
import time
from collections import deque

import numpy as np
import zenoh

from truav.bus.bus_types import UNKNOWN_SRC
from truav.bus.inbox import DEFAULT_INBOX_CAPACITY, Inbox, Received
from truav.bus.placement import check_placement, key_facts, size_limit_of_key
from truav.bus.publishing import REPLAY_TAG
from truav.wire import keys, schema
from truav.wire.guard import Guard, R_SENDER, TICK_WINDOW
from truav.wire.schema import SchemaError


MAX_UNDECODED = 65_536
"""Samples waiting to be decoded before new ones are dropped (counted as overflow on every hosted agent's bus)."""


def split_batch(key: str, batch: "schema.Beacons", run: str) -> list[tuple[str, schema.Beacon]]:
    """The beacons of a batch, each on the key its UAV would have sent it on alone, stamped with the
    batch's envelope and its own UAV as sender (the batch's sender rule is checked by the caller)."""
    out = []
    new, cls = object.__new__, schema.Beacon
    names = _names(run)
    for uav, tick, pos, vel in batch.entries:
        b = new(cls)
        key, src = names[uav]
        b.__dict__.update(src=src, seq=batch.seq, t=batch.t, inc=batch.inc, uav=uav, tick=tick, pos=pos, vel=vel)
        out.append((key, b))
    return out


@functools.lru_cache(maxsize=16)
def _names(run: str) -> tuple[tuple[str, str], ...]:
    """(beacon key, sender id) of every UAV id of a run, made once."""
    return tuple((keys.uav_beacon(run, i), keys.uav_identity(i)) for i in range(keys.MAX_UAVS))


def batch_sender_verdict(key: str, batch: "schema.Beacons") -> tuple[str, str] | None:
    """The guard's sender rule for a batch: only ``uav/<first>`` of the group its key names sends it."""
    group = keys.parse_group(key)
    if group is None or batch.src != keys.uav_identity(group[0]):
        return R_SENDER, f"beacons of group {group} from {batch.src}"
    return None


class _Chunk:
    """What one :meth:`SharedBeacons.process` decoded: valid beacons in arrival order, as Received, and
    (made once, by the first agent that asks) as columns, read by every hosted agent."""

    __slots__ = ("items", "ticks", "_columns")

    def __init__(self, items: list[Received]) -> None:
        self.items = items
        self.ticks = (min(r.msg.tick for r in items), max(r.msg.tick for r in items)) if items else (0, -1)
        self._columns = None

    def columns(self) -> "Columns":
        if self._columns is None:  # a race makes it twice, the same
            self._columns = Columns(self.items)
        return self._columns


class Columns:
    """Beacons as arrays: ``uav``, ``tick``, ``latency_ms`` (receive time minus send stamp), ``recv_ns``,
    and ``msgs`` (the Beacon objects, in the same order)."""

    __slots__ = ("uav", "tick", "latency_ms", "recv_ns", "msgs")

    def __init__(self, items: list[Received]) -> None:
        msgs = [r.msg for r in items]
        self.msgs = msgs
        self.uav = np.fromiter((b.uav for b in msgs), np.int64, len(msgs))
        self.tick = np.fromiter((b.tick for b in msgs), np.int64, len(msgs))
        self.recv_ns = np.fromiter((r.recv_ns for r in items), np.int64, len(items))
        sent = np.fromiter((b.t for b in msgs), np.int64, len(msgs))
        self.latency_ms = (self.recv_ns - sent) / 1e6


class SampleLog:
    """A growing column of numbers (or, ``width`` 2, of pairs) kept in numpy chunks: what an agent's
    beacon latency samples and their (sender, tick) cost at 1,000 agents is 8-16 bytes each, not a
    Python float or tuple. Iterates as Python floats (pairs: tuples of ints), converts with np.array."""

    def __init__(self, width: int = 1) -> None:
        self.width = width
        self._chunks: list[np.ndarray] = []
        self._tail: list = []
        self._n = 0

    def append(self, value) -> None:
        self._tail.append(value)
        self._n += 1

    def extend_array(self, values: np.ndarray) -> None:
        if len(values):
            self._seal()
            self._chunks.append(values)
            self._n += len(values)

    def _seal(self) -> None:
        if self._tail:
            dtype = np.int64 if self.width > 1 else np.float64
            self._chunks.append(np.array(self._tail, dtype=dtype).reshape(-1, self.width) if self.width > 1
                                else np.array(self._tail, dtype=dtype))
            self._tail = []

    def __array__(self, dtype=None, copy=None):
        self._seal()
        if not self._chunks:
            out = np.zeros((0, self.width) if self.width > 1 else 0)
        else:
            out = np.concatenate(self._chunks)
        return out if dtype is None else out.astype(dtype)

    def __len__(self) -> int:
        return self._n

    def __iter__(self):
        arr = np.asarray(self)
        if self.width > 1:
            return iter([tuple(row) for row in arr.tolist()])
        return iter(arr.tolist())


class BeaconView:
    """One hosted agent's beacon inbox on a :class:`SharedBeacons`: :meth:`drain` and :meth:`wait` as an
    :class:`~truav.bus.inbox.Inbox` has them, of the decoded beacons this agent's bus admitted."""

    def __init__(self, feed: "SharedBeacons", bus, inbox_opts: dict) -> None:
        self._feed, self.bus = feed, bus
        self._inbox_opts = inbox_opts
        self._own: Inbox | None = None  # what this agent's bus alone feeds in (range-limited cells)
        self.capacity = inbox_opts.get("capacity", DEFAULT_INBOX_CAPACITY)
        self._pending: list[Received] = []  # admitted, not drained yet (this view's own list)
        self._chunks: list[_Chunk] = []  # admitted whole (no filter, every tick in the window): shared
        self._delayed: list[tuple] = []  # (due mono ns, seq, recv_ns, key, msg), the link filter's delays
        self._seq = itertools.count()
        self._seen = 0  # the feed's arrival count when this view last drained

    # -- the reader's side (the agent's thread) --
    def drain(self) -> list[Received]:
        """Every valid beacon this agent's bus admitted since the last call (delays over), oldest first."""
        self._feed.process()
        with self._feed._lock:
            chunks, self._chunks = self._chunks, []
            pending, self._pending = self._pending, []
            self._seen = self._feed._done
        out: list[Received] = []
        for c in chunks:
            out.extend(c.items)
        out.extend(pending)
        if self._own is not None:
            out.extend(self._own.drain())
        if self._delayed:
            due = self._due()
            if due:
                out.extend(due)
                out.sort(key=lambda r: r.recv_ns)
        return out

    def drain_columns(self) -> list[Columns]:
        """As :meth:`drain`, in columns: a chunk every hosted agent took whole is shared, not copied."""
        self._feed.process()
        with self._feed._lock:
            chunks, self._chunks = self._chunks, []
            pending, self._pending = self._pending, []
            self._seen = self._feed._done
        out = [c.columns() for c in chunks]
        if self._own is not None:
            pending.extend(self._own.drain())
        if self._delayed:
            pending.extend(self._due())
        if pending:
            pending.sort(key=lambda r: r.recv_ns)
            out.append(Columns(pending))
        return out

    def on_sample(self, sample: zenoh.Sample) -> None:
        """A key this agent's bus subscribes to alone (``Bus.feed``: range-limited cells): its own inbox."""
        if self._own is None:
            self._own = Inbox(self.bus, **self._inbox_opts)
        self._own.on_sample(sample)

    def _due(self) -> list[Received]:
        now, out = time.monotonic_ns(), []
        with self._feed._lock:
            while self._delayed and self._delayed[0][0] <= now:
                _, _, recv_ns, key, msg = heapq.heappop(self._delayed)
                out.append((recv_ns, key, msg))
        got = []
        for recv_ns, key, msg in out:  # its own guard at delivery, as an inbox's drain checks it
            if self._feed._admits(self, key, msg):
                got.append(Received(key, msg, b"", recv_ns))
        if got:
            self.bus._count_received(0, delivered=len(got))
        return got

    def wait(self, timeout: float, min_ready: int = 1) -> bool:
        """Block until ``min_ready`` beacons may have arrived since the last drain (or one's delay ended),
        at most ``timeout`` seconds."""
        if self._delayed:
            timeout = min(timeout, max(0.0, (self._delayed[0][0] - time.monotonic_ns()) / 1e9))
        return self._feed._wait(self._seen + max(1, min_ready), timeout) or bool(
            self._delayed and self._delayed[0][0] <= time.monotonic_ns())

    def __len__(self) -> int:
        return self._feed._arrived - self._seen + len(self._delayed)


class SharedBeacons:
    """One beacon subscription, decoded once, for every agent a process hosts; call it with an agent's bus
    (``beacon_inbox`` of :class:`agents.process.agent_process.AgentNode`) to get that agent's :class:`BeaconView`.

    The subscription lives on the first agent's session (its grants allow every beacon, as every agent's
    do); with ``batched`` the batches of ``--batch-beacons`` are subscribed to as well."""

    def __init__(self, run: str, batched: bool = False) -> None:
        self.run = run
        self.key = keys.all_beacons(run)
        self.batch_key = keys.all_beacon_batches(run) if batched else None
        self.views: list[BeaconView] = []
        self._raw: deque = deque()  # (recv_ns, arrival mono ns, zenoh.Sample, arrivals so far), from the pumps
        self._lock = threading.Lock()  # the views' lists
        self._work = threading.Lock()  # one decoder at a time
        self._arrival = threading.Lock()  # two pumps with batches (one per key expression)
        self._cond = threading.Condition(threading.Lock())
        self._arrived = 0  # beacons arrived so far (a batch counts as the UAVs of its group)
        self._done = 0  # ... and handed out to the views
        self._want: int | None = None  # the smallest arrival count a waiter waits for
        self._waiters: list[int] = []
        self._guard: Guard | None = None  # the guard's sender and range rules, without a tick window
        self._clock = time.time_ns

    def __call__(self, bus, **inbox_opts) -> BeaconView:
        view = BeaconView(self, bus, inbox_opts)
        with self._lock:
            first = not self.views
            self.views = [*self.views, view]  # copied: the decoder iterates without the lock
        if first:
            self._clock = bus._clock
            bus.feed(self, self.key)
            if self.batch_key is not None:
                bus.feed(self, self.batch_key)
        return view

    # -- arrival: the first bus's pump thread(s), an append --
    def on_sample(self, sample: zenoh.Sample) -> None:
        recv_ns, mono = self._clock(), time.monotonic_ns()
        if len(self._raw) >= MAX_UNDECODED:  # nobody drains (every agent stopped) or a flood: counted
            for v in self.views:
                v.bus._count_received(1, delivered=0)
                v.bus._count_overflow()
            return
        with self._arrival:
            self._arrived += _weight(str(sample.key_expr))
            self._raw.append((recv_ns, mono, sample, self._arrived))
        want = self._want
        if want is not None and self._arrived >= want:
            with self._cond:
                self._cond.notify_all()

    def _wait(self, target: int, timeout: float) -> bool:
        with self._cond:
            if self._arrived >= target:
                return True
            self._waiters.append(target)
            self._want = min(self._waiters)
            try:
                if timeout > 0:
                    self._cond.wait(timeout)
            finally:
                self._waiters.remove(target)
                self._want = min(self._waiters) if self._waiters else None
            return self._arrived >= target

    # -- decoding, once for every view (whichever agent's thread drains first) --
    def process(self) -> None:
        """Decode what arrived and hand it to every view (see the module docstring)."""
        with self._work:
            entries = []
            while self._raw:
                try:
                    entries.append(self._raw.popleft())
                except IndexError:
                    break
            if entries:
                self._process(entries)
                self._done = entries[-1][3]

    def _process(self, entries: list[tuple]) -> None:
        views = self.views
        if self._guard is None:
            g = views[0].bus.guard
            self._guard = Guard(g.bounds) if g is not None else None
        n = len(views)
        plain = [v.bus._filters_nothing() for v in views]
        every = list(range(n))
        all_plain = all(plain)
        received = 0  # the same for every view: each PUT, a batch as the beacons it carries
        shared: list[Received] = []  # admitted by every view (no filter; tick windows checked per chunk)
        own: list[list[Received]] = [[] for _ in range(n)]  # admitted by some views only
        for recv_ns, arrival_mono, sample, _ in entries:
            if sample.kind != zenoh.SampleKind.PUT:
                continue
            received += 1
            key = str(sample.key_expr)
            got = self._gate(views, every, key, sample)
            if got is None:
                continue
            raw, open_ = got
            if key_facts(key)[0] == schema.KIND_BEACONS:
                received += self._take_batch(views, plain, open_, shared, own, key, raw, recv_ns, arrival_mono)
                continue
            # The link filter of each view that has one decides before decoding, as an inbox's does.
            admitted = open_ if all_plain else [i for i in open_ if plain[i] or self._filter(
                views[i], key, None, raw, recv_ns, arrival_mono)]
            if not admitted:
                continue
            msg = self._decode(views, admitted, key, raw)
            if msg is not None:
                self._admit(views, admitted, shared, own, Received(key, msg, raw, recv_ns))
        self._hand_out(views, received, shared, own)

    def _gate(self, views, candidates: list[int], key: str, sample: zenoh.Sample):
        """The replay tag and size checks, counted on every view that refuses; (payload, views still open)."""
        att = sample.attachment
        if att is not None and att.to_bytes() == REPLAY_TAG:
            candidates = [i for i in candidates if not views[i].bus._refuse_replayed(key, sample)]
            if not candidates:
                return None
        if len(sample.payload) > min(schema.MAX_PAYLOAD_BYTES, size_limit_of_key(key)):
            for i in candidates:
                views[i].bus._payload(key, sample, schema.MAX_PAYLOAD_BYTES)  # counts it as too large
            return None
        return sample.payload.to_bytes(), candidates

    def _filter(self, view: BeaconView, key: str, src: str | None, raw: bytes, recv_ns: int, arrival_mono: int,
                msg=None) -> bool:
        """A view's link filter on one beacon: True to admit it now; a delayed one waits in the view."""
        delay_s = view.bus._decide(key, src if src is not None else schema.peek_src(raw) or UNKNOWN_SRC, recv_ns)
        if delay_s is None:
            return False
        if delay_s <= 0:
            return True
        if msg is None:
            msg = self._decode([view], [0], key, raw)
            if msg is None:
                return False
        delay_ns = int(delay_s * 1e9)
        with self._lock:
            heapq.heappush(view._delayed, (arrival_mono + delay_ns, next(view._seq), recv_ns + delay_ns, key, msg))
        return False

    def _decode(self, views, admitted: list[int], key: str, raw: bytes):
        """Schema, placement and the guard's shared rules, once; a refusal is counted on each admitting view
        (by that view's own guard when the guard refused, so its reason and detail are its own)."""
        try:
            msg = schema.decode(raw, key_facts(key)[0])
            check_placement(key, msg)
        except SchemaError as exc:
            for i in admitted:
                views[i].bus._count_malformed(key, exc)
            return None
        verdict = self._guard.check(key, msg) if self._guard is not None else None
        if verdict is not None:
            for i in admitted:
                self._refuse(views[i], key, msg, verdict)
            return None
        return msg

    @staticmethod
    def _refuse(view: BeaconView, key: str, msg, verdict) -> None:
        g = view.bus.guard
        mine = g.check(key, msg) if g is not None else verdict
        if mine is not None:
            view.bus._count_malformed(key, SchemaError(mine[0], mine[1], src=msg.src))

    @staticmethod
    def _admits(view: BeaconView, key: str, msg) -> bool:
        """A view's own guard on a beacon the shared rules passed: only its tick window can differ."""
        g = view.bus.guard
        if g is None or _in_window(g, msg.tick):
            return True
        verdict = g.check(key, msg)
        if verdict is None:
            return True
        view.bus._count_malformed(key, SchemaError(verdict[0], verdict[1], src=msg.src))
        return False

    def _admit(self, views, admitted: list[int], shared: list, own: list, r: Received) -> None:
        if len(admitted) == len(views):
            shared.append(r)  # tick windows checked per view and chunk in _hand_out
            return
        for i in admitted:
            if self._admits(views[i], r.key, r.msg):
                own[i].append(r)

    def _take_batch(self, views, plain, open_: list[int], shared, own, key: str, raw: bytes, recv_ns: int,
                    arrival_mono: int) -> int:
        """A batch: decoded once, its sender rule checked, split into beacons each handled as if sent alone;
        returns how many beacons it carried past the one counted for it."""
        batch = self._decode(views, open_, key, raw)
        if batch is None:
            return 0
        verdict = batch_sender_verdict(key, batch)
        if verdict is not None:
            for i in open_:
                views[i].bus._count_malformed(key, SchemaError(verdict[0], verdict[1], src=batch.src))
            return 0
        parts = split_batch(key, batch, self.run)
        all_plain = all(plain[i] for i in open_)
        for bkey, b in parts:
            verdict = self._guard.check(bkey, b) if self._guard is not None else None
            if verdict is not None:
                for i in open_:
                    self._refuse(views[i], bkey, b, verdict)
                continue
            admitted = open_ if all_plain else [i for i in open_ if plain[i] or self._filter(
                views[i], bkey, b.src, raw, recv_ns, arrival_mono, msg=b)]
            if admitted:
                self._admit(views, admitted, shared, own, Received(bkey, b, raw, recv_ns))
        return len(parts) - 1

    def _hand_out(self, views, received: int, shared: list, own: list) -> None:
        chunk = _Chunk(shared) if shared else None
        for i, v in enumerate(views):
            mine, g = own[i], v.bus.guard
            whole = chunk is not None and (g is None or (_in_window(g, chunk.ticks[0])
                                                         and _in_window(g, chunk.ticks[1])))
            if chunk is not None and not whole:
                mine = [r for r in chunk.items if self._admits(v, r.key, r.msg)] + mine
            v.bus._count_received(received, delivered=(len(chunk.items) if whole else 0) + len(mine))
            if whole or mine:
                with self._lock:
                    if whole:
                        v._chunks.append(chunk)
                    if mine:
                        v._pending.extend(mine)
                    # An agent that no longer drains (it stopped; its process goes on a moment) or a flood:
                    # the oldest go, counted, as a full inbox's do.
                    while len(v._chunks) > v.capacity:
                        v._chunks.pop(0)
                        v.bus._count_overflow()
                    if len(v._pending) > v.capacity:
                        for _ in range(len(v._pending) - v.capacity):
                            v.bus._count_overflow()
                        del v._pending[:len(v._pending) - v.capacity]


def _in_window(g: Guard, tick: int) -> bool:
    cur = g.tick
    return cur is None or cur - TICK_WINDOW <= tick <= cur + TICK_WINDOW


def _weight(key: str) -> int:
    """How many beacons a sample on ``key`` may carry: a batch, its group's UAVs; else one."""
    group = keys.parse_group(key)
    return 1 if group is None else group[1] - group[0] + 1


BATCH_WAIT_S = 0.05
"""A tick's batch goes out once every hosted agent still running gave its beacon, or this long after the
first one did (a hosted agent without that tick's observation: lost, or stopping)."""


class BeaconBatcher:
    """``--batch-beacons``: the beacons of a process's hosted agents for one tick, sent as one message.

    Each agent hands its beacon to :meth:`send` (instead of publishing it on its own key); the batch
    of a tick is put on ``group/<first>-<last>/beacons`` by the first UAV's bus once every hosted
    agent still running gave its own, or BATCH_WAIT_S after the first did. Lock-step only: the real-time
    beacons go out in each UAV's own slot of the tick (agents.beacon_schedule)."""

    def __init__(self, run: str, ids: list[int]) -> None:
        self.ids = sorted(ids)
        self.key = keys.group_beacons(run, self.ids[0], self.ids[-1])
        self._live = set(self.ids)
        self._bus = None
        self._ticks: dict[int, dict[int, schema.Beacon]] = {}  # tick -> {uav: its beacon}, not sent yet
        self._first_at: dict[int, float] = {}
        self._cond = threading.Condition()
        self._closed = False
        self.sent = 0
        self._thread = threading.Thread(target=self._flusher, name="beacon-batches", daemon=True)
        self._thread.start()

    def attach(self, uav: int, bus) -> None:
        """The hosted agents' buses as they open: the first UAV's sends the batches."""
        if uav == self.ids[0]:
            self._bus = bus
            bus.prepare(self.key)

    def sender(self, uav: int):
        """What agent ``uav`` publishes its beacon with: ``send(key, beacon)``."""
        return lambda key, beacon: self.send(uav, beacon)

    def send(self, uav: int, beacon: schema.Beacon) -> None:
        with self._cond:
            for older in [t for t in self._ticks if t < beacon.tick]:  # a newer tick: the older ones go now
                self._flush(older)
            self._ticks.setdefault(beacon.tick, {})[uav] = beacon
            self._first_at.setdefault(beacon.tick, time.monotonic())
            if self._live <= self._ticks[beacon.tick].keys():
                self._flush(beacon.tick)
            else:
                self._cond.notify()

    def stopped(self, uav: int) -> None:
        """Hosted agent ``uav`` stopped: its beacon is no longer waited for."""
        with self._cond:
            self._live.discard(uav)
            for tick in [t for t, got in self._ticks.items() if self._live <= got.keys()]:
                self._flush(tick)
            if not self._live:
                self._closed = True
            self._cond.notify()

    def _flush(self, tick: int) -> None:  # under the condition's lock
        got = self._ticks.pop(tick, {})
        self._first_at.pop(tick, None)
        if not got or self._bus is None:
            return
        entries = tuple((u, b.tick, b.pos, b.vel) for u, b in sorted(got.items()))
        try:
            self._bus.publish(self.key, schema.Beacons(entries=entries))
            self.sent += 1
        except RuntimeError:  # the first UAV's bus closed at shutdown
            pass

    def _flusher(self) -> None:
        with self._cond:
            while not self._closed:
                now = time.monotonic()
                for tick in [t for t, at in self._first_at.items() if now - at >= BATCH_WAIT_S]:
                    self._flush(tick)
                due = min(self._first_at.values(), default=None)
                self._cond.wait(None if due is None else max(0.0, due + BATCH_WAIT_S - now))

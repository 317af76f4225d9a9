"""`truav-swarm view`: a live run (or a `replay`) in the Foxglove app.

Subscribes to ``truav/<run>/**`` like the recorder and serves the same mirror
channels the recorder writes into an MCAP file (``/foxglove/...`` with
Foxglove's well-known schemas, ``/json/<metrics key>``) over Foxglove's
WebSocket protocol, with ``foxglove-sdk``'s server (``foxglove.start_server``)
on loopback.  Open it in the Foxglove app: *Open connection* -> *Foxglove
WebSocket* -> ``ws://127.0.0.1:8765``, then import ``deploy/foxglove-layout.json``.

    truav-swarm view -e tcp/127.0.0.1:7447 --run demo [--port 8765] [--scenario FILE]
    truav-swarm up --foxglove 8765            # the same, started by `up`
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Optional, TypeVar

import foxglove

from recorder.foxglove import FoxgloveMirror, Out
from recorder.mcap_log import JSON_ENCODING, MIRROR_PREFIX
from recorder.schemas import MIRROR_SCHEMA_PREFIX, envelope_fields, mirror_builder, mirror_schema
from truav import jsonio
from truav.bus.transport import Bus
from truav.wire import keys

log = logging.getLogger("truav.view")

DEFAULT_PORT = 8765  # Foxglove's own default for a WebSocket connection
LOOPBACK = "127.0.0.1"
PULL_IDLE_S = 0.005
SRC_VIEW = "view"


class FoxgloveView:
    """Bus samples in, Foxglove channels out (one SDK channel per mirror topic).

    Pure of Zenoh: :meth:`handle` takes ``(key, payload, receive time)`` as the
    recorder's pull receiver yields them, so a test can feed it directly.
    """

    def __init__(self, mirror: FoxgloveMirror, context: foxglove.Context) -> None:
        self.mirror = mirror
        self.context = context
        self._channels: dict[str, foxglove.Channel] = {}
        self._json: dict[str, Optional[Callable[[dict], bytes]]] = {}  # key -> JSON mirror builder
        self._seqs: dict[tuple[str, str, int], int] = {}  # (src, kind, incarnation) -> highest seq seen
        self._srcs: set[str] = set()
        self.messages = 0  # bus samples handled
        self.errors = 0  # bodies that did not fit their kind's mirror

    def _channel(self, topic: str, schema_name: str, encoding: str, data: bytes, message_encoding: str):
        ch = self._channels.get(topic)
        if ch is None:
            ch = self._channels[topic] = foxglove.Channel(
                topic, schema=foxglove.Schema(name=schema_name, encoding=encoding, data=data),
                message_encoding=message_encoding, context=self.context)
        return ch

    def _emit(self, out: Out, t: int) -> None:
        self._channel(out.topic, out.schema.name, out.schema.encoding, out.schema.data,
                      "protobuf").log(out.data, log_time=t)

    def handle(self, key: str, payload: bytes, recv_ns: int) -> None:
        self.messages += 1
        env = envelope_fields(payload)
        if env is None:
            return
        kind, src, seq, _t, body, inc = env
        last = self._seqs.get((src, kind, inc))  # a restarted sender numbers from 0 again: a new stream
        self._seqs[(src, kind, inc)] = seq if last is None else max(seq, last)
        try:
            if src not in self._srcs:
                self._srcs.add(src)
                self._emit(self.mirror.joined(src, recv_ns), recv_ns)
            elif last is not None and seq > last + 1:
                self._emit(self.mirror.lost(src, kind, seq - last - 1, recv_ns), recv_ns)
            if key not in self._json:
                self._json[key] = mirror_builder(kind)
            build = self._json[key]
            if build is not None:
                self._channel(MIRROR_PREFIX + key, MIRROR_SCHEMA_PREFIX + kind, "jsonschema",
                              jsonio.dumps(mirror_schema(kind)).encode(), JSON_ENCODING).log(build(body), log_time=recv_ns)
            for out in self.mirror.feed(kind, body, recv_ns):
                self._emit(out, recv_ns)
        except Exception:  # an odd body: count it, keep serving
            self.errors += 1


def serve(run: str, zenoh_config: Any, mirror: FoxgloveMirror, port: int = DEFAULT_PORT,
          stop: Optional[threading.Event] = None, ready: Optional[Callable[[int], None]] = None) -> FoxgloveView:
    """Serve ``run``'s mirrors on ws://127.0.0.1:<port> until ``stop`` is set."""
    stop = stop or threading.Event()
    context = foxglove.Context()
    server = foxglove.start_server(name=f"truav {run}", host=LOOPBACK, port=port, context=context,
                                   capabilities=[foxglove.Capability.Time])
    view = FoxgloveView(mirror, context)
    last_time = 0

    def each(key: str, payload: bytes, recv_ns: int) -> None:
        nonlocal last_time
        view.handle(key, payload, recv_ns)
        if recv_ns - last_time > 50_000_000:  # the app's clock follows the bus, 20 times a second
            last_time = recv_ns
            server.broadcast_time(recv_ns)

    try:
        follow(run, zenoh_config, SRC_VIEW, stop, each, ready=lambda: ready(server.port) if ready else None)
    finally:
        server.stop()
    return view


def follow(run: str, zenoh_config: Any, src: str, stop: threading.Event,
           each: Callable[[str, bytes, int], None], every_pass: Optional[Callable[[], None]] = None,
           ready: Optional[Callable[[], None]] = None, opened: Optional[Callable[[Bus], None]] = None) -> None:
    """Every message of ``run`` (``truav/<run>/**``, raw, as the recorder subscribes) to ``each(key, payload,
    receive time)`` until ``stop`` is set; ``every_pass`` runs between messages and when none comes (a
    periodic sender's clock); ``opened`` gets the Bus first (a view that also publishes on its session).
    The live views' one subscription: Foxglove's (:func:`serve`), MAVLink's (truav/swarm/mavlink_bridge.py)
    and ROS 2's (truav/swarm/ros2_bridge.py)."""
    with Bus(src, run, zenoh_config) as bus:
        if opened is not None:
            opened(bus)
        receiver = bus.receive_raw(keys.everything(run))
        if ready is not None:
            ready()
        while not stop.is_set():
            if every_pass is not None:
                every_pass()
            item = receiver.try_recv()
            if item is None:
                time.sleep(PULL_IDLE_S)
                continue
            each(*item)


T = TypeVar("T")


@dataclass
class FedStats:
    """What a bridge made of the run's messages: every one counted, and the bodies that did not fit their kind."""
    samples: int = 0
    odd: int = 0


def feed_sample(stats: FedStats, payload: bytes, feed: Callable[[str, dict], T],
                on_shutdown: Optional[Callable[[], None]] = None) -> Optional[T]:
    """One message of the run as a bridge (MAVLink's, ROS 2's) takes it: counted, its envelope opened (None:
    not an envelope), the run's shutdown told to ``on_shutdown``, then its kind and body given to ``feed``,
    whose answer it returns; a body that did not fit its kind is counted odd (None): the bridge keeps serving."""
    stats.samples += 1
    env = envelope_fields(payload)
    if env is None:
        return None
    if env[0] == "control" and env[4].get("command") == "shutdown" and on_shutdown is not None:
        on_shutdown()
    try:
        return feed(env[0], env[4])
    except Exception:  # an odd body: count it, keep serving
        stats.odd += 1
        return None

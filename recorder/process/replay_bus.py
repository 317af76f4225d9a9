"""A replay on the bus: the :class:`recorder.replay.Replayer` publishing through a ``replay`` Bus, steered
from three places, with its status on a key of its own.

* ``control`` messages on ``truav/<run>/control/replay`` (command and args, fire and forget);
* the queryable ``truav/<run>/replay/ctl``: a query's payload is an encoded ``control`` message; the
  answer is the replay's status after the command (an encoded ``replay_status``), or a one-line error
  (``truav-swarm replay-ctl``, :func:`ask_replay`);
* a ``replay_status`` message on ``truav/<run>/replay/status`` every
  :data:`truav.wire.schema.REPLAY_STATUS_PERIOD_S` while it runs, and after every command.

``--lockstep`` (:class:`AnswerGate`): the recorded world's tick k goes out only once every live agent
(liveliness token ``alive/uav/<i>``) that was sent an observation of tick k-1 has answered it with an
action, as fast as they answer; one that does not answer within ``--lockstep-wait`` is named, marked
silent (not waited for until it answers again) and the replay goes on, as the live world does
(world.process.world_process).
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable
from typing import Any, Optional

from recorder.replay import (CMD_SEEK, CMD_STATUS, COMMANDS, CONTROL_PART, LINGER_S, KeyboardControl, LockstepGate,
                             ReplayOptions, Replayer, ReplayStats, ReplayUsageError, recording_info)
from truav.bus import transport
from truav.wire import keys, schema

log = logging.getLogger("truav.replay")

APPLY_WAIT_S = 2.0
"""A queried seek is answered once the replay has moved there (or after this long)."""
GATE_POLL_S = 0.05
MAX_CTL_QUERY_BYTES = 4096


class AnswerGate(LockstepGate):
    """``--lockstep``: holds each tick until the live agents sent an observation of the last one answered it."""

    def __init__(self, run: str, wait_s: float, report: Callable[[str], None]) -> None:
        self._run = run
        self._wait_s = wait_s
        self._report = report
        self._cond = threading.Condition()
        self._alive: set[int] = set()
        self._silent: set[int] = set()
        self._answered: dict[int, int] = {}  # uav -> newest tick answered
        self._round: Optional[int] = None  # the last tick sent
        self._asked: set[int] = set()  # UAVs sent an observation of that tick
        self.waits = 0
        self.given_up = 0  # (uav, tick) answers never received in time

    # -- the bus side --
    def attach(self, bus: transport.Bus) -> None:
        bus.subscribe(keys.all_actions(self._run), self._on_action)
        bus.watch_liveliness(keys.all_alive_uavs(self._run), self._on_join, self._on_leave)
        # The agents alive now, before the first tick: the watch reports them on another thread, which on a
        # busy host came after the first ticks were sent (and the agent was not waited for).
        for key in bus.alive(keys.all_alive_uavs(self._run), timeout=2.0):
            self._on_join(key)

    def _on_action(self, key: str, msg: schema.Message, raw: bytes, recv_ns: int) -> None:
        if isinstance(msg, schema.Action) and msg.src == keys.uav_identity(msg.uav):
            with self._cond:
                self._answered[msg.uav] = max(self._answered.get(msg.uav, -1), msg.tick)
                if msg.uav in self._silent:
                    self._silent.discard(msg.uav)
                self._cond.notify_all()

    def _on_join(self, key: str) -> None:
        uav = keys.parse_uav_id(key)
        if uav is not None:
            with self._cond:
                self._alive.add(uav)
                self._silent.discard(uav)
                self._cond.notify_all()

    def _on_leave(self, key: str) -> None:
        uav = keys.parse_uav_id(key)
        if uav is not None:
            with self._cond:
                self._alive.discard(uav)
                self._cond.notify_all()

    # -- the replay side --
    def published(self, key: str, payload: bytes) -> None:
        if key == keys.world_tick(self._run):
            msg = _decode(payload)
            if isinstance(msg, schema.Tick):
                with self._cond:
                    self._round, self._asked = msg.tick, set()
        elif key.endswith(f"/{keys.OBS}"):
            uav = keys.parse_uav_id(key)
            msg = _decode(payload)
            if uav is not None and isinstance(msg, schema.Obs):
                with self._cond:
                    if msg.tick == self._round:
                        self._asked.add(uav)

    def alive(self) -> set[int]:
        with self._cond:
            return set(self._alive)

    def wait_answers(self, interrupted: Callable[[], bool]) -> None:
        with self._cond:
            tick = self._round
            if tick is None:
                return
            self.waits += 1
            limit = time.monotonic() + self._wait_s
            while True:
                waiting = self._waiting_for(tick)
                if not waiting or interrupted():
                    return
                if time.monotonic() >= limit:
                    break
                self._cond.wait(GATE_POLL_S)
            self._silent.update(waiting)
            self.given_up += len(waiting)
        self._report(f"lockstep: uav {', '.join(map(str, sorted(waiting)))} did not answer tick {tick} within "
                     f"{self._wait_s:g} s (--lockstep-wait); going on without it (not waited for until it "
                     f"answers again)")

    def _waiting_for(self, tick: int) -> set[int]:
        return {u for u in (self._asked & self._alive) - self._silent if self._answered.get(u, -1) < tick}


def _decode(payload: bytes) -> Optional[schema.Message]:
    try:
        return schema.decode(payload)
    except schema.SchemaError:  # a recorded payload the schema refuses: not a round of this replay
        return None


def control_args(msg: schema.Control) -> dict[str, Any]:
    """The arguments of a command message, as :meth:`Replayer.command` takes them."""
    return {str(k): v for k, v in msg.args.items()}


def ctl_handler(replayer: Replayer, sequencer: schema.Sequencer,
                publish_status: Callable[[], None]) -> Callable[[bytes], tuple[bool, bytes]]:
    """The queryable's handler: an encoded control message in, the encoded status (or an error) out."""

    def handle(payload: bytes) -> tuple[bool, bytes]:
        try:
            msg = schema.decode(payload, expect=schema.KIND_CONTROL)
        except schema.SchemaError as exc:
            return False, f"not a control message: {exc}".encode()
        if not isinstance(msg, schema.Control):
            return False, b"not a control message"
        try:
            replayer.command(msg.command, **control_args(msg))
        except (ValueError, TypeError) as exc:
            return False, str(exc).encode()
        if msg.command == CMD_SEEK:
            deadline = time.monotonic() + APPLY_WAIT_S
            while replayer.seeking() and time.monotonic() < deadline:
                time.sleep(0.01)
        if msg.command != CMD_STATUS:
            publish_status()
        return True, schema.encode(sequencer.stamp(replayer.status()))

    return handle


def replay_on_bus(options: ReplayOptions, zenoh_config: Any = None, *, keyboard: bool = False,
                  stop: Optional[threading.Event] = None,
                  on_state: Callable[[str], None] = lambda _state: None) -> ReplayStats:
    """Replay through a ``replay`` Bus, obeying bus commands and queries (and the keyboard if asked),
    publishing its status. ``stop`` (optional) ends the replay from another thread (e.g. a signal handler)."""
    info = recording_info(options.path)
    probe_replayer = Replayer(options, lambda k, p: None, info)  # validates options before opening Zenoh
    run = probe_replayer.target_run
    if run is None:
        raise ReplayUsageError(f"{options.path}: no truav/<run>/ keys to replay")
    with transport.Bus(keys.SRC_REPLAY, run, zenoh_config) as bus:
        gate = AnswerGate(run, options.lockstep_wait_s, on_state) if options.lockstep else None
        replayer = Replayer(options, bus.publish_raw, info, on_state=on_state, gate=gate)
        if gate is not None:
            gate.attach(bus)
        status_lock = threading.Lock()

        def publish_status() -> None:
            with status_lock:
                if not bus.closed:
                    bus.publish(keys.replay_status(run), replayer.status())

        def on_control(key: str, msg: schema.Message, raw: bytes, recv_ns: int) -> None:
            if isinstance(msg, schema.Control) and msg.command in COMMANDS:
                try:
                    replayer.command(msg.command, **control_args(msg))
                except (ValueError, TypeError) as exc:
                    on_state(f"{msg.command} from {msg.src} refused: {exc}")
                    return
                publish_status()

        bus.subscribe(keys.control(run, CONTROL_PART), on_control)
        bus.serve(keys.replay_ctl(run), ctl_handler(replayer, schema.Sequencer(keys.SRC_REPLAY), publish_status),
                  MAX_CTL_QUERY_BYTES)
        done = threading.Event()

        def status_loop() -> None:
            while not done.wait(schema.REPLAY_STATUS_PERIOD_S):
                try:
                    publish_status()
                except RuntimeError:  # the bus closed under us: the replay is over
                    return

        ticker = threading.Thread(target=status_loop, name="truav-replay-status", daemon=True)
        ticker.start()
        if stop is not None:
            threading.Thread(target=lambda: (stop.wait(), replayer.quit("interrupted")), daemon=True).start()
        context = KeyboardControl(replayer) if keyboard else contextlib.nullcontext()
        try:
            with context:
                stats = replayer.run()
        finally:
            done.set()
            ticker.join(1.0)
            if stop is not None:
                stop.set()  # release the watcher
        if gate is not None:
            stats.lockstep_held, stats.lockstep_given_up = gate.waits, gate.given_up
        publish_status()  # the last word: ended
        time.sleep(LINGER_S)
    return stats


def ask_replay(bus: transport.Bus, run: str, command: str, args: dict[str, Any],
               timeout: float = 5.0) -> schema.ReplayStatus:
    """Send one command to the replay of ``run`` over its queryable; its status after it.
    ``transport.QueryRefused`` (one line) when no replay answers or it refuses the command."""
    payload = schema.encode(schema.Sequencer(bus.identity).stamp(schema.Control(command=command, args=args)))
    answer = bus.ask(keys.replay_ctl(run), payload, timeout=timeout, max_bytes=schema.MAX_SMALL_PAYLOAD_BYTES)
    try:
        status = schema.decode(answer, expect=schema.KIND_REPLAY_STATUS)
    except schema.SchemaError as exc:
        raise transport.QueryRefused(f"the answer on {keys.replay_ctl(run)} is not a replay status: {exc}") from None
    assert isinstance(status, schema.ReplayStatus)
    return status


def status_line(s: schema.ReplayStatus) -> str:
    """A replay status in one line, as replay-ctl prints it."""
    tick = f" tick {s.tick}" if s.tick >= 0 else ""
    return (f"{s.state} at {s.position_s:.3f}/{s.span_s:.3f} s{tick}, rate {s.rate:g}, {s.sent} sent"
            + (f", {s.restored} restored" if s.restored else "") + (f", loop {s.loop}" if s.loop else ""))

"""Re-publish a recording onto Zenoh with its original timing (``truav-swarm replay FILE``).

What rosbag2 users expect, on the TRUAV bus:

* the recorded payloads go out unchanged (``src``/``seq``/``t`` preserved),
  through a Bus of identity ``replay`` (``keys.SRC_REPLAY``), which may
  publish anywhere under its run, UAV keys included;
* message *i* is due ``(log_time_i - log_time_first) / rate`` after the first
  was sent (monotonic clock), so the receive-time spacing of the recording is
  reproduced; ``--rate`` scales it, ``--loop`` starts over at the end;
* ``--topics``/``--exclude`` filter keys with globs (``*`` also matches
  ``/``; ``!PATTERN`` in ``--topics`` excludes); ``--start``/``--duration``
  cut a window, in seconds from the first message of the recording;
* ``--run NEW`` rewrites the key prefix ``truav/<old>/`` to ``truav/NEW/``;
* ``--paused`` starts paused; while it plays, :meth:`Replayer.command` (any thread: the keyboard,
  a ``control`` message on ``truav/<run>/control/replay``, the ``truav/<run>/replay/ctl`` queryable
  of :mod:`recorder.process.replay_bus`) pauses, resumes, sets the rate, steps one world tick (every message
  up to the next world tick message: from a tick's start, that whole tick; paused in the middle of
  one, the rest of it), bursts N ticks, steps N messages, or seeks to a
  time (seconds from the recording's first message), to a tick, or by a time back or forward.
  After a seek the last message of every replayed channel before the new position is sent again
  first, so a subscriber that joined late sees the current state (rosbag2 #929); a seek to tick N lands
  just past tick N's world tick message (sent with that state: the replay is at tick N); see
  :data:`KEY_BINDINGS` and :data:`COMMANDS`;
* several files, or a split recording's parts, play as one (:mod:`recorder.replay_source`).

Recorded ``control`` keys are skipped unless ``--with-control`` (re-sending
old ``stop``/``shutdown`` commands into a live run is rarely wanted), and
``control/replay`` and a recorded replay's own ``replay/*`` always are (a replay
must not steer itself). ``--lockstep`` leaves out the recorded actions: the live
agents answer (:class:`LockstepGate`, :mod:`recorder.process.replay_bus`).

Driving one live agent from a recorded world: replay only what the world
sent to it, and let the live agent answer::

    truav-swarm agent --id 3 --run demo -e tcp/127.0.0.1:7447 &
    truav-swarm replay demo.mcap -e tcp/127.0.0.1:7447 \\
        --topics 'truav/*/world/tick' 'truav/*/uav/3/obs' 'truav/*/uav/[!3]*/beacon'

(the last pattern replays the other agents' beacons, so its neighbour
features are as recorded; ``[!3]*`` is fnmatch's "not starting with 3").

:class:`Replayer` is the engine; it publishes through any callable, so it
is tested without Zenoh too. Its options and the checks made before it starts are
:mod:`recorder.replay_setup`; the replay on the bus, :mod:`recorder.process.replay_bus`.
"""

from __future__ import annotations

import os
import select
import sys
import threading
import time
from collections.abc import Callable, Iterator
from fnmatch import fnmatchcase
from typing import IO, Any, Optional

from recorder.reader import RecordedMessage
from recorder.replay_setup import (  # noqa: F401  (re-exported: what a replay is asked to do)
    ACTION_PATTERN, CONTROL_PART, CONTROL_PATTERN, NS, SELF_CONTROL_PATTERN, SELF_STATUS_PATTERN, RecordingInfo,
    ReplayOptions, ReplayStats, ReplayUsageError, effective_excludes, key_rewriter, recording_info, select_topics,
    split_patterns)
from recorder.replay_source import ReplaySource, TICK_PATTERN, Timeline, resolve_parts, tick_of
from truav.wire import schema

CMD_PAUSE, CMD_RESUME, CMD_TOGGLE, CMD_STEP, CMD_QUIT = "pause", "resume", "toggle", "step", "quit"
CMD_BURST, CMD_NEXT, CMD_SEEK, CMD_RATE, CMD_STATUS = "burst", "next", "seek", "rate", "status"
COMMANDS = (CMD_PAUSE, CMD_RESUME, CMD_TOGGLE, CMD_STEP, CMD_BURST, CMD_NEXT, CMD_SEEK, CMD_RATE, CMD_STATUS,
            CMD_QUIT)
"""What :meth:`Replayer.command` takes, with its arguments: ``step`` ``n`` ticks (default 1) and ``burst``
``n`` ticks (both leave it paused; a tick ends where the next world tick message starts), ``next`` ``n``
messages, ``seek`` with one of ``s`` (seconds from the recording's first message), ``tick`` or ``by``
(seconds, negative: back), ``rate`` with ``rate`` (> 0) or ``factor`` (multiplies it), ``status``
(nothing: the answer is the status)."""
BURST_KEY_TICKS = 10
SKIP_KEY_S = 5.0
MIN_RATE, MAX_RATE = 1e-3, 1e3
KEY_BINDINGS: dict[str, tuple[str, dict[str, Any]]] = {
    " ": (CMD_TOGGLE, {}), "s": (CMD_STEP, {}), "n": (CMD_NEXT, {}), "b": (CMD_BURST, {"n": BURST_KEY_TICKS}),
    "+": (CMD_RATE, {"factor": 2.0}), "=": (CMD_RATE, {"factor": 2.0}), "-": (CMD_RATE, {"factor": 0.5}),
    ",": (CMD_SEEK, {"by": -SKIP_KEY_S}), ".": (CMD_SEEK, {"by": SKIP_KEY_S}), "0": (CMD_SEEK, {"s": 0.0}),
    "q": (CMD_QUIT, {}),
}
ENTRY_KEYS = {"g": "tick", "t": "s"}
"""Keys that start typing a seek target: g then a tick number, t then seconds from the start; Enter
seeks, Esc (or any other key) cancels, Backspace deletes."""
MAX_ENTRY_CHARS = 16
KEYS_HELP = (f"space pause/resume, s step one tick, b burst {BURST_KEY_TICKS} ticks, n one message, + / - rate x2 / "
             f"x0.5, , / . back / forward {SKIP_KEY_S:g} s, 0 to the start, g<tick>Enter go to a tick, "
             f"t<seconds>Enter go to a time, q quit")
"""The keys, as --help and the banner say them."""

KEY_POLL_S = 0.1  # keyboard thread wake-up (to notice the end)
LINGER_S = 0.2  # after the last put, before closing the session: let Zenoh send it
SPIN_S = 0.0005  # wait the last half millisecond by polling: Condition.wait overshoots ~0.1 ms


class LockstepGate:
    """What ``--lockstep`` needs from the bus (:class:`recorder.process.replay_bus.AnswerGate`): told of every
    message sent, it holds the next tick back until the live agents answered the last one."""

    def published(self, key: str, payload: bytes) -> None:
        """A message went out (a tick opens a round; an observation names a UAV to wait for)."""

    def wait_answers(self, interrupted: Callable[[], bool]) -> None:
        """Return once the open round is answered, given up on, or ``interrupted()``."""


def _count(args: dict[str, Any], name: str, default: int) -> int:
    n = args.get(name, default)
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 1_000_000:
        raise ValueError(f"{name} must be an integer in [1, 1000000], got {n!r}")
    return n


def _number(args: dict[str, Any], name: str) -> float:
    v = args[name]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or v != v or v in (float("inf"), float("-inf")):
        raise ValueError(f"{name} must be a finite number, got {v!r}")
    return float(v)


class Replayer:
    """Publishes a recording with its timing; every command of :data:`COMMANDS` from any thread.

    Positions count the messages of the replayed stream (:class:`recorder.replay_source.Timeline`):
    ``_pos`` is the next one to send. A seek takes effect in the loop (:meth:`run`'s thread): it moves
    the stream there, sends each channel's last message before it, and plays on from it at once."""

    def __init__(self, options: ReplayOptions, publish: Callable[[str, bytes], None],
                 info: Optional[RecordingInfo] = None, clock: Callable[[], int] = time.monotonic_ns,
                 on_state: Callable[[str], None] = lambda _state: None, gate: Optional[LockstepGate] = None) -> None:
        if not options.rate > 0:
            raise ReplayUsageError(f"--rate must be positive, got {options.rate}")
        if options.start_s < 0 or (options.duration_s is not None and options.duration_s <= 0):
            raise ReplayUsageError("--start must be >= 0 and --duration > 0")
        if options.loops is not None and options.loops < 1:
            raise ReplayUsageError("loops must be at least 1")
        if not options.lockstep_wait_s > 0:
            raise ReplayUsageError(f"--lockstep-wait must be positive, got {options.lockstep_wait_s}")
        self.options = options
        self.info = info if info is not None else recording_info(options.path)
        if options.run is None and len(self.info.runs) > 1:
            raise ReplayUsageError(f"{self._name()} holds runs {', '.join(self.info.runs)}: pick one with --run")
        span_s = (self.info.last_ns - self.info.first_ns) / NS
        if options.start_s > span_s:
            raise ReplayUsageError(f"--start {options.start_s:g} s is past the end of the recording ({span_s:.3f} s)")
        self.topics = select_topics(self.info, options)
        self._send = frozenset(self.topics)
        ticks = [t for t in self.info.topics if fnmatchcase(t, TICK_PATTERN)]
        self._scan = sorted(self._send | set(ticks))  # tick keys are read for step/seek even when not sent
        self.source = ReplaySource(self.info.paths or tuple(resolve_parts(options.path)))
        self.target_run = options.run or (self.info.runs[0] if self.info.runs else None)
        self._rewrite = key_rewriter(options.run)
        self._publish = publish
        self._clock = clock
        self._on_state = on_state
        self._gate = gate
        self._cond = threading.Condition()
        self._timeline: Optional[Timeline] = None
        self._paused = options.paused
        self._rate = float(options.rate)
        self._quit: Optional[str] = None
        self._pos = 0  # the next message of the stream to send
        self._until = 0  # paused: send on while _pos < _until (step, burst, next)
        self._seek: Optional[int] = None  # a position to move to, taken by the loop
        self._anchor: Optional[tuple[int, int]] = None  # (monotonic ns, log time ns) that are due together
        self._last_log: Optional[int] = None  # receive time of the last message sent
        self._tick = -1  # the last world tick sent
        self._waiting = False  # --lockstep: for the agents' answers
        self._ended = False
        self._entry: Optional[tuple[str, str]] = None  # a seek target being typed: (argument, text so far)
        self._last: dict[str, RecordedMessage] = {}  # each channel's last message up to _pos
        self.stats = ReplayStats()

    def _name(self) -> str:
        paths = self.info.paths
        return str(paths[0]) if len(paths) == 1 else f"{len(paths)} files" if paths else str(self.options.path)

    # -- where it stands --
    @property
    def paused(self) -> bool:
        return self._paused

    @property
    def rate(self) -> float:
        return self._rate

    @property
    def timeline(self) -> Timeline:
        """Every message's receive time and where each tick starts (one read of the window, on first use)."""
        with self._cond:
            if self._timeline is None:
                start, end = self.window()
                self._timeline = Timeline.scan(self.source.messages(self._scan, start, end),
                                               lambda key: fnmatchcase(key, TICK_PATTERN))
            return self._timeline

    def status(self) -> schema.ReplayStatus:
        """Where it stands, as the status message says it (unstamped)."""
        with self._cond:
            state = (schema.REPLAY_ENDED if self._ended or self._quit else schema.REPLAY_WAITING if self._waiting
                     else schema.REPLAY_PAUSED if self._paused else schema.REPLAY_PLAYING)
            last = self._last_log if self._last_log is not None else self.window()[0]
            return schema.ReplayStatus(
                state=state, position_s=max(last - self.info.first_ns, 0) / NS,
                span_s=(self.info.last_ns - self.info.first_ns) / NS, tick=self._tick, rate=self._rate,
                paused=self._paused, sent=self.stats.published, restored=self.stats.restored, loop=self.stats.loops)

    def describe(self) -> str:
        """The status in one line."""
        s = self.status()
        tick = f", tick {s.tick}" if s.tick >= 0 else ""
        return (f"{s.state} at {s.position_s:.3f}/{s.span_s:.3f} s{tick}, rate {s.rate:g}, {s.sent} sent"
                + (f", {s.restored} restored" if s.restored else ""))

    # -- commands (any thread) --
    def key(self, char: str) -> bool:
        """Apply the command bound to a key (:data:`KEY_BINDINGS`), or type a seek target
        (:data:`ENTRY_KEYS`); False for an unbound key. ValueError (one line) for a refused seek."""
        if self._entry is not None:
            return self._type(char)
        if char in ENTRY_KEYS:
            self._entry = (ENTRY_KEYS[char], "")
            self._on_state(f"go to {'tick' if char == 'g' else 'time (s)'}: type it, then Enter (Esc cancels)")
            return True
        binding = KEY_BINDINGS.get(char.lower() if char.isalpha() else char)
        if binding is None:
            return False
        self.command(binding[0], **binding[1])
        return True

    def _type(self, char: str) -> bool:
        assert self._entry is not None
        what, text = self._entry
        if char in ("\r", "\n"):
            self._entry = None
            try:
                value: Any = int(text) if what == "tick" else float(text)
            except ValueError:
                raise ValueError(f"not a {'tick number' if what == 'tick' else 'time in seconds'}: {text!r}") from None
            self.command(CMD_SEEK, **{what: value})
        elif char in ("\x7f", "\b"):
            self._entry = (what, text[:-1])
        elif (char.isdigit() or (char == "." and what == "s")) and len(text) < MAX_ENTRY_CHARS:
            self._entry = (what, text + char)
        else:  # Esc or anything else: no seek
            self._entry = None
            self._on_state("seek cancelled")
        return True

    def command(self, name: str, **args: Any) -> None:
        """Apply one of :data:`COMMANDS`; ValueError (one line) for an unknown command or a bad argument."""
        if name not in COMMANDS:
            raise ValueError(f"unknown replay command {name!r}; known: {', '.join(COMMANDS)}")
        timeline = self.timeline if name in (CMD_STEP, CMD_BURST, CMD_NEXT, CMD_SEEK) else None
        with self._cond:
            if name == CMD_PAUSE or (name == CMD_TOGGLE and not self._paused):
                self._paused = True
            elif name in (CMD_RESUME, CMD_TOGGLE):
                if self._paused:
                    self._paused, self._anchor = False, None
            elif name in (CMD_STEP, CMD_BURST):
                n = _count(args, "n", 1)
                end = max(self._next_position(), self._until)
                for _ in range(n):
                    end = timeline.next_tick_start(end)
                self._paused, self._until = True, end
            elif name == CMD_NEXT:
                self._paused = True
                self._until = min(max(self._next_position(), self._until) + _count(args, "n", 1), len(timeline))
            elif name == CMD_SEEK:
                self._seek = self._seek_position(timeline, args)
                self._until = self._seek
            elif name == CMD_RATE:
                self._set_rate(args)
            elif name == CMD_QUIT:
                self._quit = self._quit or "quit command"
            self._cond.notify_all()
        self._on_state(f"{name}{_args_text(args)}: {self.describe()}")

    def _next_position(self) -> int:
        return self._seek if self._seek is not None else self._pos

    def _seek_position(self, timeline: Timeline, args: dict[str, Any]) -> int:
        given = [k for k in ("s", "tick", "by") if k in args]
        if len(given) != 1:
            raise ValueError("seek takes one of s (seconds from the start), tick, or by (seconds, negative: back)")
        if given[0] == "tick":
            tick = args["tick"]
            if isinstance(tick, bool) or not isinstance(tick, int):
                raise ValueError(f"tick must be an integer, got {tick!r}")
            # just past the tick's own world tick message: it goes out with the restored state, so the
            # replay is at that tick (its status says so), and a step plays the rest of it
            return timeline.position_of_tick(tick) + 1
        span_s = (self.info.last_ns - self.info.first_ns) / NS
        if given[0] == "s":
            at = _number(args, "s")
            if not 0 <= at <= span_s:
                raise ValueError(f"s={at:g} is outside the recording (0 to {span_s:.3f} s)")
            return timeline.position_at(self.info.first_ns + round(at * NS))
        here = self._last_log if self._last_log is not None else self.window()[0]
        return timeline.position_at(here + round(_number(args, "by") * NS))

    def _set_rate(self, args: dict[str, Any]) -> None:
        rate = self._rate * _number(args, "factor") if "factor" in args else _number(args, "rate") if "rate" in args \
            else None
        if rate is None or not MIN_RATE <= rate <= MAX_RATE:
            raise ValueError(f"rate takes rate (or factor) giving a speed in [{MIN_RATE:g}, {MAX_RATE:g}]"
                             + ("" if rate is None else f", got {rate:g}"))
        if self._anchor is not None and not self._paused:  # the recorded time reached so far stays reached
            now = self._clock()
            mono, log = self._anchor
            self._anchor = (now, log + round((now - mono) * self._rate))
        self._rate = rate

    def seeking(self) -> bool:
        """A seek is waiting for the loop to take it."""
        with self._cond:
            return self._seek is not None and self._quit is None and not self._ended

    def report(self, line: str) -> None:
        """A line for the console (a refused key, a lock-step warning)."""
        self._on_state(line)

    def quit(self, reason: str = "quit") -> None:
        with self._cond:
            self._quit = self._quit or reason
            self._cond.notify_all()

    # -- the loop --
    def window(self) -> tuple[int, Optional[int]]:
        """[start, end) receive-time bounds of the replayed window, ns."""
        start = self.info.first_ns + round(self.options.start_s * NS)
        end = None if self.options.duration_s is None else start + round(self.options.duration_s * NS)
        return start, end

    def messages(self) -> Iterator[RecordedMessage]:
        """The replayed stream: the kept keys, and the world's ticks (read, sent only if kept)."""
        start, end = self.window()
        return self.source.messages(self._scan, start, end)

    def run(self) -> ReplayStats:
        """Replay until the end (of every loop) or quit; returns the statistics."""
        stats = self.stats
        began = self._clock()
        self.timeline  # read the window once before the first message goes out
        loop = 0
        while self.options.loops is None or loop < self.options.loops:
            if not self._run_once():
                break
            loop += 1
            stats.loops = loop
        with self._cond:
            stats.quit_reason = self._quit or "end"
            self._ended = True
        stats.wall_s = (self._clock() - began) / NS
        self._on_state(f"ended: {self.describe()}")
        return stats

    def _run_once(self) -> bool:
        """One pass over the window; False when quit.

        A message is due at ``anchor_mono + (log_time - anchor_log) / rate``. The anchor is the first
        message of the pass, and moves when a pause ends (to the last message sent, so the recorded gap
        to the next one is kept), a message is stepped or a seek lands (to that message), or the rate
        changes (to the recorded time reached then)."""
        clock = self._clock
        with self._cond:
            # a step asked for before the first pass began stays asked for
            self._pos, self._anchor, self._last = 0, None, {}
            self._until = self._until if self._seek is None and not self.stats.loops else 0
            self._last_log, self._tick = None, -1
        stream = self.messages()
        current = next(stream, None)
        while True:
            stepped = False
            with self._cond:
                while True:
                    if self._quit:
                        return False
                    if self._seek is not None:
                        break
                    if self._paused:
                        if current is not None and self._pos < self._until:
                            stepped = True
                            break
                        self._cond.wait()
                        continue
                    if current is None:
                        return True
                    if current.key not in self._send or (self.options.lockstep and self._gate is not None):
                        break  # not sent (a tick key kept for stepping), or as fast as the agents answer
                    if self._anchor is None:
                        self._anchor = (clock(), current.log_time if self._last_log is None else self._last_log)
                    mono, log = self._anchor
                    left = mono + round((current.log_time - log) / self._rate) - clock()
                    if left <= 0:
                        break
                    if left > SPIN_S * NS:
                        self._cond.wait((left - SPIN_S * NS) / NS)
                    else:  # spin the last bit, without holding the lock
                        due = clock() + left
                        self._cond.release()
                        try:
                            while clock() < due:
                                pass
                        finally:
                            self._cond.acquire()
                seek = self._seek
            if seek is not None:
                stream, current = self._move(stream, current, seek)
                continue
            assert current is not None
            if current.key in self._send and not self._hold_for_answers(current):
                continue  # a seek or quit came while waiting: look again
            self._send_message(current, restored=False, timed=not stepped)
            if stepped:
                with self._cond:
                    self._anchor = (clock(), current.log_time)
            with self._cond:
                self._pos += 1
            current = next(stream, None)

    def _hold_for_answers(self, message: RecordedMessage) -> bool:
        """--lockstep: before a tick goes out, wait for the answers to the last one; False if interrupted."""
        if self._gate is None or not fnmatchcase(message.key, TICK_PATTERN):
            return True
        with self._cond:
            self._waiting = True
        try:
            self._gate.wait_answers(lambda: self._quit is not None or self._seek is not None)
        finally:
            with self._cond:
                self._waiting = False
        return self._quit is None and self._seek is None

    def _send_message(self, message: RecordedMessage, restored: bool, timed: bool = False) -> None:
        """Publish one message; ``timed``: it went out at its due time (its lateness is counted)."""
        out_key = self._rewrite(message.key)
        if fnmatchcase(message.key, TICK_PATTERN):
            tick = tick_of(message.payload)
            if tick is not None:
                self._tick = tick
        if out_key is None or message.key not in self._send:
            return
        now = self._clock()
        self._publish(out_key, message.payload)
        if self._gate is not None:
            self._gate.published(out_key, message.payload)
        with self._cond:
            self._last_log = message.log_time
            self._last[message.key] = message
            if restored:
                self.stats.restored += 1
                return
            self.stats.published += 1
            self.stats.per_channel[out_key] += 1
            if timed and self._anchor is not None and not self.options.lockstep:
                mono, log = self._anchor
                self.stats.add_lateness(now - mono - round((message.log_time - log) / self._rate))

    def _move(self, stream: Iterator[RecordedMessage], current: Optional[RecordedMessage],
              target: int) -> tuple[Iterator[RecordedMessage], Optional[RecordedMessage]]:
        """Go to position ``target``: read forward (from the start when going back) keeping each channel's
        last message, send those again in their recorded order, and play on from ``target`` at once."""
        with self._cond:
            pos = self._pos
            if target < pos:
                stream, pos, self._last = self.messages(), 0, {}
                current = next(stream, None)
            last = self._last
        tick = -1 if pos == 0 else self._tick
        while current is not None and pos < target:
            if current.key in self._send:
                last[current.key] = current
            if fnmatchcase(current.key, TICK_PATTERN):
                number = tick_of(current.payload)
                tick = tick if number is None else number
            pos += 1
            current = next(stream, None)
        self._tick = tick
        with self._cond:
            self._last_log = None  # the position is now the restored messages' (none: the start)
        for message in sorted(last.values(), key=lambda m: m.log_time):
            self._send_message(message, restored=True)
        with self._cond:
            self._pos = pos
            self._anchor = None if current is None else (self._clock(), current.log_time)  # on at once
            if self._seek == target:
                self._seek = None
            self._until = max(self._until, pos)
            self.stats.seeks += 1
        self._on_state(f"at position {pos}: {self.describe()}")
        return stream, current


def _args_text(args: dict[str, Any]) -> str:
    return "".join(f" {k}={v}" for k, v in args.items())


# --- keyboard -------------------------------------------------------------------------------
class KeyboardControl:
    """Single keys on a terminal (cbreak mode, restored on exit): :data:`KEY_BINDINGS`."""

    def __init__(self, replayer: Replayer, stream: IO[str] = sys.stdin) -> None:
        self._replayer = replayer
        self._stream = stream
        self._done = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self._saved: Any = None

    @staticmethod
    def available(stream: IO[str] = sys.stdin) -> bool:
        """A terminal we can put in cbreak mode (not a pipe, not a background job's lost tty)."""
        try:
            if not stream.isatty():
                return False
            import termios

            termios.tcgetattr(stream.fileno())
            return os.getpgrp() == os.tcgetpgrp(stream.fileno())  # foreground: reading will not stop us
        except Exception:  # termios.error is not an OSError; no tty of any kind means no keyboard
            return False

    def __enter__(self) -> "KeyboardControl":
        import termios
        import tty

        fd = self._stream.fileno()
        self._saved = termios.tcgetattr(fd)
        tty.setcbreak(fd)
        self._thread = threading.Thread(target=self._loop, name="truav-replay-keys", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        import termios

        self._done.set()
        if self._thread is not None:
            self._thread.join(KEY_POLL_S * 5)
        termios.tcsetattr(self._stream.fileno(), termios.TCSADRAIN, self._saved)

    def _loop(self) -> None:
        fd = self._stream.fileno()
        while not self._done.is_set():
            ready, _, _ = select.select([fd], [], [], KEY_POLL_S)
            if not ready:
                continue
            char = os.read(fd, 1).decode(errors="ignore")
            if not char:  # a byte of a multi-byte character: no key of ours
                continue
            try:
                self._replayer.key(char)
            except ValueError as exc:  # e.g. a seek past the end: say it, keep playing
                self._replayer.report(f"key {char!r}: {exc}")

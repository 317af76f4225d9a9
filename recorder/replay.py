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
* ``--paused`` starts paused; then, on a terminal, *space* pauses/resumes,
  *s* steps one message, *q* quits; on the bus, a ``control`` message on
  ``truav/<run>/control/replay`` with command ``pause``, ``resume``,
  ``toggle``, ``step`` (``args: {"n": k}`` for k messages) or ``quit``.

Recorded ``control`` keys are skipped unless ``--with-control`` (re-sending
old ``stop``/``shutdown`` commands into a live run is rarely wanted), and
``control/replay`` always is (a replay must not steer itself).

Driving one live agent from a recorded world: replay only what the world
sent to it, and let the live agent answer::

    truav-swarm agent --id 3 --run demo -e tcp/127.0.0.1:7447 &
    truav-swarm replay demo.mcap -e tcp/127.0.0.1:7447 \\
        --topics 'truav/*/world/tick' 'truav/*/uav/3/obs' 'truav/*/uav/[!3]*/beacon'

(the last pattern replays the other agents' beacons, so its neighbour
features are as recorded; ``[!3]*`` is fnmatch's "not starting with 3").

:class:`Replayer` is the engine; it publishes through any callable, so it
is tested without Zenoh too.
"""

from __future__ import annotations

import contextlib
import os
import select
import sys
import threading
import time
from array import array
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from fnmatch import fnmatchcase
from pathlib import Path
from typing import IO, Any, Optional

from recorder.mcap_log import is_mirror_topic
from recorder.reader import RecordedMessage, iter_messages, open_source, probe, read_schemas
from truav.bus import keys, schema, transport

CONTROL_PART = "replay"  # commands arrive on keys.control(run, CONTROL_PART)
CMD_PAUSE, CMD_RESUME, CMD_TOGGLE, CMD_STEP, CMD_QUIT = "pause", "resume", "toggle", "step", "quit"
COMMANDS = (CMD_PAUSE, CMD_RESUME, CMD_TOGGLE, CMD_STEP, CMD_QUIT)
KEY_BINDINGS = {" ": CMD_TOGGLE, "s": CMD_STEP, "q": CMD_QUIT}

CONTROL_PATTERN = "truav/*/control/*"  # recorded control keys: skipped by default
SELF_CONTROL_PATTERN = f"truav/*/control/{CONTROL_PART}"  # never replayed
NS = 1_000_000_000
MAX_LATENESS_SAMPLES = 1_000_000  # timing statistics keep every k-th sample beyond this
KEY_POLL_S = 0.1  # keyboard thread wake-up (to notice the end)
LINGER_S = 0.2  # after the last put, before closing the session: let Zenoh send it
SPIN_S = 0.0005  # wait the last half millisecond by polling: Condition.wait overshoots ~0.1 ms


class ReplayUsageError(ValueError):
    """A user mistake (missing file, not an MCAP, a pattern matching nothing...)."""


@dataclass(frozen=True)
class ReplayOptions:
    path: Path
    run: Optional[str] = None  # publish under truav/<run>/ (default: the recorded run)
    rate: float = 1.0
    loops: Optional[int] = 1  # None: forever
    include: tuple[str, ...] = ()  # empty: every key
    exclude: tuple[str, ...] = ()
    start_s: float = 0.0
    duration_s: Optional[float] = None
    paused: bool = False
    with_control: bool = False


@dataclass
class ReplayStats:
    """What a replay did, and how well it kept time."""

    published: int = 0
    per_channel: Counter = field(default_factory=Counter)  # output key -> messages
    loops: int = 0  # complete passes
    wall_s: float = 0.0
    quit_reason: str = "end"
    lateness_ns: array = field(default_factory=lambda: array("q"))  # send time - due time, when not paused
    _sample_every: int = 1

    def add_lateness(self, late_ns: int) -> None:
        if self.published % self._sample_every == 0:
            self.lateness_ns.append(late_ns)
            if len(self.lateness_ns) >= MAX_LATENESS_SAMPLES:
                del self.lateness_ns[::2]
                self._sample_every *= 2

    def lateness_ms(self, q: float) -> float:
        """Quantile ``q`` of the lateness, in ms (0 when nothing was timed)."""
        if not self.lateness_ns:
            return 0.0
        ordered = sorted(self.lateness_ns)
        return ordered[min(int(q * len(ordered)), len(ordered) - 1)] / 1e6

    def format(self) -> str:
        return (f"replay: {self.published} messages on {len(self.per_channel)} channels in {self.wall_s:.2f} s, "
                f"{self.loops} complete pass(es), ended by {self.quit_reason}; timing: late by "
                f"p50 {self.lateness_ms(0.5):.2f} ms, p99 {self.lateness_ms(0.99):.2f} ms, "
                f"max {self.lateness_ms(1.0):.2f} ms")


@dataclass(frozen=True)
class RecordingInfo:
    """What a replay needs to know before it starts."""

    first_ns: int  # first receive time in the file (None-free: empty files are refused)
    last_ns: int
    topics: tuple[str, ...]  # bus keys (mirrors excluded)
    runs: tuple[str, ...]  # the <run> of every truav/<run>/ key


def recording_info(path: str | os.PathLike[str]) -> RecordingInfo:
    """Span and keys of a recording; ReplayUsageError when it is missing, not MCAP or empty."""
    path = Path(path)
    if not path.is_file():
        raise ReplayUsageError(f"{path}: no such file")
    try:
        with open_source(path) as stream:
            probe(stream)
        topics = tuple(sorted(t for t in read_schemas(path) if not is_mirror_topic(t)))
        first = last = None
        summary = _finished_summary(path)
        if summary is not None and summary.statistics is not None and summary.statistics.message_count:
            first, last = summary.statistics.message_start_time, summary.statistics.message_end_time
        else:
            for message in iter_messages(path):
                first = message.log_time if first is None else min(first, message.log_time)
                last = message.log_time if last is None else max(last, message.log_time)
    except ValueError as exc:  # probe: "not an MCAP file"
        raise ReplayUsageError(f"{path}: {exc}") from None
    if first is None or last is None:
        raise ReplayUsageError(f"{path}: the recording holds no messages")
    runs = tuple(sorted({r for r in map(keys.parse_run, topics) if r is not None}))
    return RecordingInfo(first_ns=first, last_ns=last, topics=topics, runs=runs)


def _finished_summary(path: Path) -> Any:
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        if not probe(f).finished:
            return None
        f.seek(0)
        try:
            return make_reader(f).get_summary()
        except Exception:  # a damaged summary: fall back to scanning
            return None


def split_patterns(topics: Sequence[str], exclude: Sequence[str] = ()) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """``--topics`` entries starting with ``!`` are excludes; returns (include, exclude)."""
    include = tuple(t for t in topics if not t.startswith("!"))
    excluded = tuple(t[1:] for t in topics if t.startswith("!")) + tuple(exclude)
    for pattern in include + excluded:
        if not pattern:
            raise ReplayUsageError("empty topic pattern")
    return include, excluded


def effective_excludes(options: ReplayOptions) -> tuple[str, ...]:
    base = (SELF_CONTROL_PATTERN,) if options.with_control else (CONTROL_PATTERN,)
    return base + tuple(options.exclude)


def select_topics(info: RecordingInfo, options: ReplayOptions) -> list[str]:
    """Recorded keys the options keep; ReplayUsageError if a pattern selects nothing."""
    excludes = effective_excludes(options)
    for pattern in options.include:
        if not any(fnmatchcase(t, pattern) for t in info.topics):
            raise ReplayUsageError(f"--topics {pattern!r} matches no recorded key; keys are: "
                                   + ", ".join(info.topics[:20]) + (" ..." if len(info.topics) > 20 else ""))
    kept = [t for t in info.topics
            if (not options.include or any(fnmatchcase(t, p) for p in options.include))
            and not any(fnmatchcase(t, p) for p in excludes)]
    if not kept:
        raise ReplayUsageError("the topic filters leave nothing to replay (recorded control keys are skipped "
                               "unless --with-control)")
    return kept


def key_rewriter(target_run: Optional[str]) -> Callable[[str], Optional[str]]:
    """Key in the file -> key to publish (None: not a TRUAV key, skipped)."""
    if target_run is not None:
        try:
            keys.validate_run(target_run)
        except ValueError as exc:
            raise ReplayUsageError(f"--run: {exc}") from None

    def rewrite(key: str) -> Optional[str]:
        run = keys.parse_run(key)
        if run is None:
            return None
        if target_run is None:
            return key
        return f"{keys.prefix(target_run)}{key[len(keys.ROOT) + 1 + len(run):]}"

    return rewrite


class Replayer:
    """Publishes a recording with its timing; pause/resume/step/quit from any thread."""

    def __init__(self, options: ReplayOptions, publish: Callable[[str, bytes], None],
                 info: Optional[RecordingInfo] = None, clock: Callable[[], int] = time.monotonic_ns,
                 on_state: Callable[[str], None] = lambda _state: None) -> None:
        if not options.rate > 0:
            raise ReplayUsageError(f"--rate must be positive, got {options.rate}")
        if options.start_s < 0 or (options.duration_s is not None and options.duration_s <= 0):
            raise ReplayUsageError("--start must be >= 0 and --duration > 0")
        if options.loops is not None and options.loops < 1:
            raise ReplayUsageError("loops must be at least 1")
        self.options = options
        self.info = info if info is not None else recording_info(options.path)
        if options.run is None and len(self.info.runs) > 1:
            raise ReplayUsageError(f"{options.path} holds runs {', '.join(self.info.runs)}: pick one with --run")
        span_s = (self.info.last_ns - self.info.first_ns) / NS
        if options.start_s > span_s:
            raise ReplayUsageError(f"--start {options.start_s:g} s is past the end of the recording ({span_s:.3f} s)")
        self.topics = select_topics(self.info, options)
        self.target_run = options.run or (self.info.runs[0] if self.info.runs else None)
        self._rewrite = key_rewriter(options.run)
        self._publish = publish
        self._clock = clock
        self._on_state = on_state
        self._cond = threading.Condition()
        self._paused = options.paused
        self._steps = 0
        self._quit: Optional[str] = None
        self._resumed = False  # set when leaving a pause: re-anchor the timing
        self.stats = ReplayStats()

    # -- commands (any thread) --
    @property
    def paused(self) -> bool:
        return self._paused

    def command(self, name: str, n: int = 1) -> None:
        """Apply one of :data:`COMMANDS`; ValueError for anything else."""
        with self._cond:
            if name == CMD_PAUSE or (name == CMD_TOGGLE and not self._paused):
                self._paused = True
            elif name == CMD_RESUME or name == CMD_TOGGLE:
                if self._paused:
                    self._paused, self._resumed = False, True
            elif name == CMD_STEP:
                self._paused = True
                self._steps += max(int(n), 1)
            elif name == CMD_QUIT:
                self._quit = self._quit or "quit command"
            else:
                raise ValueError(f"unknown replay command {name!r}; known: {', '.join(COMMANDS)}")
            self._cond.notify_all()
            state = "quitting" if self._quit else ("paused" if self._paused else "playing")
        self._on_state(f"{state} ({name}, {self.stats.published} sent)")

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
        start, end = self.window()
        return iter_messages(self.options.path, include=self.topics, start_ns=start, end_ns=end)

    def run(self) -> ReplayStats:
        """Replay until the end (of every loop) or quit; returns the statistics."""
        stats = self.stats
        began = self._clock()
        loop = 0
        while self.options.loops is None or loop < self.options.loops:
            if not self._run_once():
                break
            loop += 1
            stats.loops = loop
        with self._cond:
            stats.quit_reason = self._quit or "end"
        stats.wall_s = (self._clock() - began) / NS
        return stats

    def _run_once(self) -> bool:
        """One pass over the window; False when quit.

        Message i is due at ``anchor_mono + (log_time_i - anchor_log) / rate``.
        The anchor is the first message of the pass, and moves when a pause
        ends (to the last message sent, so the recorded gap to the next one is
        kept) or a message is stepped (to that message).
        """
        anchor_mono: Optional[int] = None
        anchor_log = 0
        last_log: Optional[int] = None  # receive time of the last message sent
        scale = 1.0 / self.options.rate
        clock = self._clock
        for message in self.messages():
            out_key = self._rewrite(message.key)
            if out_key is None:
                continue
            if anchor_mono is None:
                anchor_mono, anchor_log = clock(), message.log_time
            stepped = False
            with self._cond:
                while True:
                    if self._quit:
                        return False
                    if self._paused:
                        if self._steps:
                            self._steps -= 1
                            stepped = True
                            break
                        self._cond.wait()
                        continue
                    if self._resumed:
                        self._resumed = False
                        anchor_mono = clock()
                        anchor_log = message.log_time if last_log is None else last_log
                    left = anchor_mono + round((message.log_time - anchor_log) * scale) - clock()
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
            now = clock()
            self._publish(out_key, message.payload)
            if stepped:
                anchor_mono, anchor_log = now, message.log_time
            else:
                self.stats.add_lateness(now - anchor_mono - round((message.log_time - anchor_log) * scale))
            last_log = message.log_time
            self.stats.published += 1
            self.stats.per_channel[out_key] += 1
        return True


# --- keyboard -------------------------------------------------------------------------------
class KeyboardControl:
    """Single keys on a terminal (cbreak mode, restored on exit): space, s, q."""

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
            command = KEY_BINDINGS.get(char.lower())
            if command is not None:
                self._replayer.command(command)


# --- running it on the bus -------------------------------------------------------------------
def replay_on_bus(options: ReplayOptions, zenoh_config: Any = None, *, keyboard: bool = False,
                  stop: Optional[threading.Event] = None,
                  on_state: Callable[[str], None] = lambda _state: None) -> ReplayStats:
    """Replay through a ``replay`` Bus, obeying bus commands (and the keyboard if asked).
    ``stop`` (optional) ends the replay from another thread (e.g. a signal handler)."""
    info = recording_info(options.path)
    probe_replayer = Replayer(options, lambda k, p: None, info)  # validates options before opening Zenoh
    run = probe_replayer.target_run
    if run is None:
        raise ReplayUsageError(f"{options.path}: no truav/<run>/ keys to replay")
    with transport.Bus(keys.SRC_REPLAY, run, zenoh_config) as bus:
        replayer = Replayer(options, bus.publish_raw, info, on_state=on_state)

        def on_control(key: str, msg: schema.Message, raw: bytes, recv_ns: int) -> None:
            if isinstance(msg, schema.Control) and msg.command in COMMANDS:
                n = msg.args.get("n", 1)
                replayer.command(msg.command, n if isinstance(n, int) and not isinstance(n, bool) else 1)

        bus.subscribe(keys.control(run, CONTROL_PART), on_control)
        watcher = None
        if stop is not None:
            watcher = threading.Thread(target=lambda: (stop.wait(), replayer.quit("interrupted")), daemon=True)
            watcher.start()
        context = KeyboardControl(replayer) if keyboard else contextlib.nullcontext()
        with context:
            stats = replayer.run()
        if stop is not None:
            stop.set()  # release the watcher
        time.sleep(LINGER_S)
    return stats

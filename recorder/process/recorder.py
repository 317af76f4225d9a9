"""The recorder as a Zenoh process: everything under ``truav/<run>/`` into one MCAP file.

This module is the recording node (:class:`Recorder`, its options and summary,
and :func:`record`, the process's life); its command line is
:mod:`truav.cli.log_process`.  Run it alone, or let a supervisor start it as a
subprocess (:func:`recorder_argv`)::

    python -m truav.cli.log_process --run RUN --out FILE -e tcp/127.0.0.1:PORT [--config-toml FILE]

(``python -m recorder.process`` is the same command, its spelling before the
split; ``truav log record`` and its alias ``truav-swarm record`` are the same
with the ``truav`` flags checked first.)  The process prints nothing on
stdout but one summary when it stops, and exits

* 0 after SIGTERM, SIGINT or a ``stop`` control message on
  ``truav/<run>/control/recorder``, once the file is finished (footer
  written, readable by mcap's ``make_reader``); started alone (no supervisor),
  also when the run it records ends (:meth:`Recorder.follow_run`), and it says
  on stderr what it records and where, then its progress;
* 2 for a user mistake (bad run name, output exists without ``--force``,
  config not TOML ...), with a one-line message on stderr;
* 1 when recording failed (router unreachable, disk full ...).

The same control key takes ``split`` (recording in parts), ``pause``, ``resume`` and ``snapshot``
(snapshot mode), as does SIGHUP (split) and SIGUSR1 (snapshot); see :mod:`recorder.record_modes`
for the layouts (one file, parts, snapshots) and ``truav log record-ctl`` to send them.

It is *recording* once its liveliness token ``truav/<run>/alive/recorder``
is visible: the token is declared after the subscription, so a supervisor
that waits for it (:func:`wait_until_recording`) loses no message it sends
afterwards.  :func:`recorder_argv`, :func:`spawn_recorder` and
:func:`stop_recorder` wrap the subprocess life cycle.

Thread model.  The writer thread owns the :class:`~recorder.mcap_log.McapLog`
(not thread-safe) and pulls samples itself from a bounded Zenoh FIFO
(:meth:`truav.bus.transport.Bus.receive_raw`): no Python callback and no thread
hand-off per message, which doubled the sustained rate against a callback
design. When the bus is quiet it sleeps 1 ms at a time and flushes at the
log's :meth:`~recorder.mcap_log.McapLog.next_flush_due`, so the open chunk
reaches the OS within ``flush_interval`` even without traffic (the SIGKILL
loss bound). A full FIFO pushes back on Zenoh's queues instead of dropping
in this process. The main thread only waits for a stop request.

Log time is the time the writer pulls the sample (wall clock, ns); publish time is the sender's envelope
``t``; see :mod:`recorder.mcap_log` for the file layout.
"""

from __future__ import annotations

import contextlib
import logging
import os
import queue
import signal
import socket
import subprocess
import sys
import threading
import time
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from recorder.mcap_log import (
    COMPRESSIONS,
    DEFAULT_CHUNK_BYTES,
    DEFAULT_COMPRESSION,
    DEFAULT_FLUSH_INTERVAL_S,
    LIBRARY,
    McapLog,
)
from recorder.foxglove import DEFAULT_ORIGIN, FoxgloveMirror, Geometry
from recorder.recover import compact
from recorder.metadata import (CONFIG_METADATA, RECORDING_METADATA, RUN_METADATA, SUMMARY_METADATA, config_metadata,
                               run_info_metadata)
from recorder.parts import PartedLog
from recorder.pause import PauseLedger
from recorder.record_modes import (MODE_FLAGS, PAUSE_METADATA, REASON_COMMAND, REASON_SIGNAL, RecordModes,
                                   part_path, parts_index_path, snapshot_path)
from recorder.snapshot import SnapshotLog
from recorder.snapshot_triggers import COMMAND, SIGNAL, Trigger
from recorder.summary import RecorderSummary
from truav import jsonio
from truav.bus import transport
from truav.errors import UserError
from truav.lifecycle import signals_handled, watch_supervisor
from truav.lograte import Every
from truav.options import to_argv
from truav.wire import keys, schema

log = logging.getLogger("truav.recorder")

# --- names other tools rely on ---------------------------------------------------------
ENTRY_MODULE = "truav.cli.log_process"  # `python -m ENTRY_MODULE` runs the recorder (recorder_argv)
CONTROL_PART = "recorder"  # commands arrive on keys.control(run, CONTROL_PART)
CMD_STOP = "stop"
CMD_SPLIT, CMD_PAUSE, CMD_RESUME, CMD_SNAPSHOT = "split", "pause", "resume", "snapshot"
COMMANDS = (CMD_STOP, CMD_SPLIT, CMD_PAUSE, CMD_RESUME, CMD_SNAPSHOT)
COMPACT_MAX_BYTES = 64 * 1024 * 1024
"""A clean finish compacts a single file up to this size (seconds of work); a longer one keeps its chunks as
written (already bounded: DEFAULT_CHUNK_BYTES, compressed as they fill), so the finish stays fast."""
MB = 1_000_000

# --- timing ------------------------------------------------------------------------------
IDLE_WAKE_S = 0.25  # writer wake-up when nothing is pending (bounds stop latency, costs nothing)
WRITER_JOIN_TIMEOUT_S = 60.0  # a large backlog takes a while to write
DEFAULT_READY_TIMEOUT_S = 10.0
STOP_GRACE_S = 10.0  # stop_recorder: SIGTERM, then SIGKILL after this long
RUN_END_GRACE_S = 1.0  # standalone: recording on after the run's last process left (its last messages)
RUN_END_MAX_WAIT_S = 20.0  # standalone: the longest it waits for the run's processes to leave after its end
PROGRESS_S = 10.0  # standalone: a progress line on stderr this often
CONTROL_SHUTDOWN = "shutdown"  # truav/<run>/control/shutdown: the world's end of a run (and `truav-swarm down`)
WORLD_LEFT = "the world left"

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2

_STOP = object()  # queue sentinel: everything before it gets written


class RecorderUsageError(ValueError):
    """A user mistake (bad option, existing output...): reported in one line, exit code 2."""


@dataclass(frozen=True)
class RecorderOptions:
    """What to record and how; see ``python -m truav.cli.log_process --help``."""

    run: str
    out: Path
    config_toml: Optional[str] = None  # the run's config as TOML text (stored as MCAP metadata)
    run_info: Optional[dict] = None  # how the run was started beyond its config (seed, lock-step...: RUN_METADATA)
    compression: str = DEFAULT_COMPRESSION
    flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S
    chunk_bytes: int = DEFAULT_CHUNK_BYTES
    mirrors: bool = True
    fsync: bool = False
    force: bool = False  # overwrite an existing output file
    geo_origin: tuple[float, float] = DEFAULT_ORIGIN  # (lat, lon) of the area's centre in Foxglove's Map panel
    compact: bool = True  # rewrite into bigger, bounded chunks at a clean finish (recorder.recover.compact)
    modes: RecordModes = RecordModes()  # one file, parts or snapshots (recorder.record_modes)

    def validate(self) -> "RecorderOptions":
        """Raise RecorderUsageError for anything a user can get wrong; return self."""
        try:
            keys.validate_run(self.run)
        except ValueError as exc:
            raise RecorderUsageError(str(exc)) from None
        if self.compression not in COMPRESSIONS:
            raise RecorderUsageError(f"compression must be one of {sorted(COMPRESSIONS)}, got {self.compression!r}")
        if not self.flush_interval_s > 0 or self.chunk_bytes <= 0:
            raise RecorderUsageError("the flush interval and chunk size must be positive")
        out = Path(self.out)
        if out.is_dir():
            raise RecorderUsageError(f"{out} is a directory; give a file name such as {out / 'run.mcap'}")
        try:
            self.modes.validate()
        except UserError as exc:
            raise RecorderUsageError(str(exc)) from None
        first = part_path(out, 1) if self.modes.split else snapshot_path(out, 1) if self.modes.snapshot else out
        if self.modes.split and parts_index_path(out).exists() and not first.exists():
            first = parts_index_path(out)  # an earlier recording's index (its parts moved away)
        if first.exists() and not self.force:
            raise RecorderUsageError(f"{first} exists; use --force to overwrite it")
        if not out.parent.is_dir():
            raise RecorderUsageError(f"directory {out.parent} does not exist")
        if self.config_toml is not None:
            try:
                tomllib.loads(self.config_toml)
            except tomllib.TOMLDecodeError as exc:
                raise RecorderUsageError(f"the run config is not valid TOML: {exc}") from None
        return self


PULL_IDLE_S = 0.001  # writer sleep when the bus is quiet (bounds added latency, not the flush)
BURST = 4096  # samples written between checks for a stop request


def _scene_geometry(config_toml: Optional[str]) -> Geometry:
    """The Foxglove scene's geometry from the run config; the default scenario's (with a
    warning) for a config this version cannot read: the recording itself must not fail."""
    try:
        return Geometry.from_toml(config_toml)
    except ValueError as exc:
        log.warning("recorder: the Foxglove scene uses the default geometry: the run config was not usable (%s)",
                    exc)
        return Geometry()


class Recorder:
    """Subscribes to ``truav/<run>/**`` and writes every sample to an MCAP file.

    ``start()`` opens the file and the Bus; ``stop()`` finishes the file and
    returns the summary; ``stop_requested`` is set by a ``stop`` control
    message or a writer failure (the caller decides when to call ``stop``).
    A context manager stops on exit.
    """

    def __init__(self, options: RecorderOptions, zenoh_config: Any = None) -> None:
        self.options = options.validate()
        self._zconfig = zenoh_config
        self.stop_requested = threading.Event()
        self.stop_reason = "stopped"
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._log: Optional[McapLog] = None
        self._bus: Optional[transport.Bus] = None
        self._handles: list[transport.Handle] = []
        self._writer: Optional[threading.Thread] = None
        self._error: Optional[str] = None
        self._max_backlog = 0
        self.written = 0  # messages handed to the log so far (-v lines), but those of the last pull at the stop
        self._started_ns = 0
        self._summary: Optional[RecorderSummary] = None
        self._pause: Optional[PauseLedger] = None  # set while paused (writer thread only)
        self._run_lock = threading.Lock()
        self._run_end: Optional[tuple[str, float]] = None  # follow_run: (why the run ended, monotonic time of it)
        self._alive: set[str] = set()  # follow_run: the run's processes with a liveliness token (but ours)
        self._quiet_since: Optional[float] = time.monotonic()  # follow_run: since when none is alive
        self.world_seen = False  # follow_run: the world's liveliness token was seen
        self._paused_ns = 0
        self._paused_messages = 0

    # -- life cycle --
    def start(self) -> "Recorder":
        """Open the file, then the Bus; subscribe, then declare liveliness (= ready)."""
        opts = self.options
        self._started_ns = time.time_ns()
        try:
            self._log = self._open_sink()
        except OSError as exc:
            raise RecorderUsageError(f"cannot write {opts.out}: {exc.strerror or exc}") from None
        try:
            self._log.set_metadata(RECORDING_METADATA, {
                "run": opts.run, "started_ns": str(self._started_ns),
                "started": time.strftime("%Y-%m-%dT%H:%M:%S%z", time.localtime(self._started_ns / 1e9)),
                "host": socket.gethostname(), "recorder": LIBRARY, "schema_version": str(schema.SCHEMA_VERSION),
                "key_prefix": keys.prefix(opts.run) + "/",
            })
            if opts.config_toml is not None:
                self._log.set_metadata(CONFIG_METADATA, config_metadata(opts.config_toml))
            if opts.run_info is not None:
                self._log.set_metadata(RUN_METADATA, run_info_metadata(opts.run_info))
            self._bus = transport.Bus(keys.SRC_RECORDER, opts.run, self._zconfig)
            # Pulled by the writer thread itself: no per-message callback or hand-off.
            self._receiver = self._bus.receive_raw(keys.everything(opts.run))
            self._writer = threading.Thread(target=self._write_loop, name="truav-recorder-writer", daemon=True)
            self._writer.start()
            self._handles.append(self._bus.subscribe(keys.control(opts.run, CONTROL_PART), self._on_control))
            self._handles.append(self._bus.declare_liveliness(keys.alive_recorder(opts.run)))
        except BaseException:
            self._abort_start()
            raise
        return self

    def _open_sink(self) -> "McapLog | PartedLog | SnapshotLog":
        """The file(s) the writer thread writes: one McapLog, or parts, or snapshots of McapLogs."""
        opts = self.options
        fox = FoxgloveMirror(_scene_geometry(opts.config_toml), opts.geo_origin) if opts.mirrors else False

        def make_log(path: Path) -> McapLog:
            return McapLog(path, compression=opts.compression, flush_interval_s=opts.flush_interval_s,
                           chunk_bytes=opts.chunk_bytes, mirrors=opts.mirrors, foxglove=fox, fsync=opts.fsync)

        modes = opts.modes
        if modes.split:
            return PartedLog(opts.out, modes, make_log, repeat=(RECORDING_METADATA, CONFIG_METADATA, RUN_METADATA))
        window = modes.window
        if window is not None:
            return SnapshotLog(opts.out, window[0], window[1], int(modes.snapshot_max_mb * MB), make_log)
        return make_log(opts.out)

    @property
    def files(self) -> list[Path]:
        """The files written so far (parts, snapshots, or the one file)."""
        sink = self._log
        if isinstance(sink, (PartedLog, SnapshotLog)):
            return list(sink.paths)
        return [Path(self.options.out)]

    def request(self, command: str, by: str, signalled: bool = False) -> None:
        """Ask the writer thread to split, pause, resume or snapshot (safe from a signal handler and
        from the bus's threads: the writer alone touches the files); ``signalled``: by a signal."""
        self._queue.put((command, by, time.time_ns(), signalled))

    def follow_run(self) -> None:
        """Standalone (no supervisor to stop it): end by itself when the run ends. The run ends with a
        ``shutdown`` on ``truav/<run>/control/shutdown`` (the world publishes it at the run's end, as
        ``truav-swarm down`` does), or when the world's liveliness token, once seen, is gone (a world that
        died; it records on if the world comes back). It then records until every process of the run has left
        (no liveliness token of the run but its own) and :data:`RUN_END_GRACE_S` more, at most
        :data:`RUN_END_MAX_WAIT_S`; :meth:`run_end` says when. Call after :meth:`start`."""
        assert self._bus is not None, "follow_run() before start()"
        run = self.options.run
        self._handles.append(self._bus.subscribe(keys.control(run, CONTROL_SHUTDOWN), self._on_shutdown))
        self._handles.append(self._bus.watch_liveliness(keys.all_alive(run), lambda k: self._on_token(k, True),
                                                        lambda k: self._on_token(k, False)))

    def _on_shutdown(self, key: str, msg: schema.Message, raw: bytes, recv_ns: int) -> None:
        with self._run_lock:
            if self._run_end is None or self._run_end[0] == WORLD_LEFT:
                self._run_end = (f"the run ended (shutdown from {msg.src})", time.monotonic())

    def _on_token(self, key: str, up: bool) -> None:
        who = key.split("/alive/", 1)[-1]
        if who == "recorder":
            return
        with self._run_lock:
            (self._alive.add if up else self._alive.discard)(who)
            self._quiet_since = None if self._alive else time.monotonic()
            if who != "world":
                return
            if up:
                self.world_seen = True
                if self._run_end is not None and self._run_end[0] == WORLD_LEFT:
                    self._run_end = None  # back (a brief disconnection): record on
            elif self.world_seen and self._run_end is None:
                self._run_end = (WORLD_LEFT, time.monotonic())

    def run_end(self) -> tuple[Optional[str], bool]:
        """(why the run ended, or None; whether to stop now: its processes left a grace ago, or it waited
        the longest). Only with :meth:`follow_run`."""
        with self._run_lock:
            if self._run_end is None:
                return None, False
            reason, since = self._run_end
            now, quiet = time.monotonic(), self._quiet_since
            return reason, (quiet is not None and now - quiet >= RUN_END_GRACE_S) or now - since >= RUN_END_MAX_WAIT_S

    def _abort_start(self) -> None:
        """Startup failed: stop what runs and remove the (empty) file we created."""
        if self._bus is not None:
            self._bus.close()
        if self._writer is not None:
            self._queue.put(_STOP)
            self._writer.join(WRITER_JOIN_TIMEOUT_S)
        if self._log is not None:
            with contextlib.suppress(Exception):
                self._log.close()
            leftovers = self.files + ([parts_index_path(self.options.out)] if self.options.modes.split else [])
            for path in leftovers:
                with contextlib.suppress(OSError):
                    os.unlink(path)

    def stop(self, reason: Optional[str] = None) -> RecorderSummary:
        """Unsubscribe, write everything received, finish the file. Idempotent."""
        if self._summary is not None:
            return self._summary
        if reason is not None:
            self.stop_reason = reason
        bus, logfile = self._bus, self._log
        if bus is None or logfile is None:
            raise RuntimeError("stop() before start()")
        for handle in self._handles:
            handle.close()
        self._queue.put(_STOP)  # the writer drains what Zenoh already handed over, then stops
        assert self._writer is not None
        self._writer.join(WRITER_JOIN_TIMEOUT_S)
        if self._writer.is_alive():
            self._error = self._error or f"writer did not finish within {WRITER_JOIN_TIMEOUT_S:.0f} s"
        bus_stats = bus.stats()
        bus.close()  # the liveliness token goes with the session
        if self._pause is not None and not self._writer.is_alive():  # stopped while paused: say so in the file
            with contextlib.suppress(Exception):
                self._end_pause("stop")
        summary = RecorderSummary(
            run=self.options.run, path=os.fspath(self.options.out), started_ns=self._started_ns,
            stopped_ns=time.time_ns(), stop_reason=self.stop_reason, log=logfile.summary(), bus=bus_stats,
            max_backlog=self._max_backlog, error=self._error, paused_s=self._paused_ns / 1e9,
            not_recorded_paused=self._paused_messages,
        )
        if not self._writer.is_alive():  # the writer is done with the log: safe to finish it here
            try:
                if not logfile.closed:
                    meta = {k: v for k, v in summary.to_json().items() if k not in ("channels", "senders")}
                    logfile.set_metadata(SUMMARY_METADATA, meta)
                logfile.close()
            except Exception as exc:  # disk full and the like: report it, the flushed chunks stay recoverable
                detail = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
                summary.error = self._error = f"finishing {self.options.out} failed: {detail}"
            else:
                summary.files = [os.fspath(p) for p in self.files]
                single = isinstance(logfile, McapLog)
                if self.options.compact and self._error is None and single \
                        and os.path.getsize(self.options.out) <= COMPACT_MAX_BYTES:
                    try:
                        summary.compacted = compact(self.options.out, compression=self.options.compression)
                    except Exception as exc:  # the finished (uncompacted) file is still there and valid
                        log.warning("recorder: compacting %s failed (%s); kept the file as written",
                                    self.options.out, exc)
        self._summary = summary
        return summary

    def __enter__(self) -> "Recorder":
        return self.start()

    def __exit__(self, *_exc: object) -> None:
        if self._bus is not None:
            self.stop()

    @property
    def error(self) -> Optional[str]:
        return self._error

    # -- callbacks (Bus delivery thread) --
    def _on_control(self, key: str, msg: schema.Message, raw: bytes, recv_ns: int) -> None:
        command = msg.command if isinstance(msg, schema.Control) else None
        if command == CMD_STOP:
            self.stop_reason = f"stop command from {msg.src}"
            self.stop_requested.set()
        elif command in COMMANDS:  # under --secure only the supervisor may put on control/* (truav.bus.acl)
            self.request(command, msg.src)
        else:
            log.warning("recorder: ignoring control command %r from %s (known: %s)",
                        getattr(msg, "command", msg.KIND), msg.src, ", ".join(COMMANDS))

    # -- requests (writer thread) --
    def _apply_requests(self) -> bool:
        """Carry out the queued requests in order; True once the stop sentinel is reached."""
        while True:
            try:
                item = self._queue.get_nowait()
            except queue.Empty:
                return False
            if item is _STOP:
                return True
            self._apply(*item)

    def _apply(self, command: str, by: str, at_ns: int, signalled: bool) -> None:
        sink = self._log
        if command == CMD_PAUSE:
            if self._pause is None:
                self._pause = PauseLedger(at_ns, by)
                log.info("recorder: paused by %s", by)
        elif command == CMD_RESUME:
            if self._pause is not None:
                self._end_pause(by)
                log.info("recorder: resumed by %s", by)
        elif command == CMD_SPLIT:
            if isinstance(sink, PartedLog):
                path = sink.split(REASON_SIGNAL if signalled else REASON_COMMAND)
                log.info("recorder: split by %s; now writing %s", by, path)
            else:
                log.warning("recorder: ignoring split from %s: not recording in parts "
                            "(--split-size, --split-duration or --split-on-command)", by)
        elif command == CMD_SNAPSHOT:
            if isinstance(sink, SnapshotLog):
                sink.trigger(Trigger(SIGNAL if signalled else COMMAND, at_ns, f"{command} from {by}"))
            else:
                log.warning("recorder: ignoring snapshot from %s: not in snapshot mode (--snapshot)", by)

    def _end_pause(self, by: str) -> None:
        ledger, now = self._pause, time.time_ns()
        assert ledger is not None and self._log is not None
        self._pause = None
        self._paused_ns += now - ledger.started_ns
        self._paused_messages += ledger.messages
        self._log.set_metadata(PAUSE_METADATA, ledger.record(now, by))

    def _write_fn(self):
        if self._pause is None:
            return self._log.write  # type: ignore[union-attr]
        ledger, log_ = self._pause, self._log

        def skip(key: str, payload: bytes, log_time_ns: int, publish_time_ns: Optional[int] = None) -> None:
            ledger.skip(key, payload, log_time_ns, publish_time_ns)
            log_.skip(payload)  # type: ignore[union-attr]
        return skip

    # -- the writer thread --
    def _write_waiting(self, pull, write) -> int:
        """Write the samples already waiting, at most one FIFO's worth; how many were written."""
        n = 0
        while n < transport.DEFAULT_PULL_CAPACITY and (item := pull()) is not None:
            write(*item)
            n += 1
        return n

    def _write_loop(self) -> None:
        """Sole owner of the McapLog: pull samples in bursts, flush on the log's timer.

        Ends on _STOP (put by stop()) after writing every sample still waiting."""
        logfile = self._log
        assert logfile is not None
        pull, clock, requests = self._receiver.try_recv, time.monotonic, self._queue
        try:
            write = self._write_fn()
            while True:
                if not requests.empty():
                    # A command takes effect after the samples that reached this process before it: the control
                    # callback runs once Zenoh has put the earlier samples of its link in the FIFO, so a split
                    # or pause applies in arrival order. Bounded by the FIFO's size, so a flood cannot starve it.
                    self.written += self._write_waiting(pull, write)
                    if self._apply_requests():  # stop: the samples still waiting, then done
                        write = self._write_fn()
                        while (item := pull()) is not None:
                            write(*item)
                        return
                    write = self._write_fn()
                item = pull()
                if item is None:
                    logfile.maybe_flush()
                    due = logfile.next_flush_due()
                    pause = PULL_IDLE_S if due is None else min(max(due - clock(), 0.0), PULL_IDLE_S)
                    time.sleep(pause)
                    continue
                write(*item)  # closes the chunk itself once it is flush_interval old
                burst = 1
                while burst < BURST and (item := pull()) is not None:
                    write(*item)
                    burst += 1
                self.written += burst
                if burst > self._max_backlog:
                    self._max_backlog = burst
        except Exception as exc:  # disk full, I/O error: stop recording, keep what was flushed
            self._error = f"writing {self.options.out} failed: {exc}"
            log.error("recorder: %s", self._error)
            self.stop_reason = "write error"
            self.stop_requested.set()


# --- running it ----------------------------------------------------------------------------
def short_error(exc: BaseException) -> str:
    """An exception as one line; Zenoh's errors end in " at <rust source path>", which users need not read."""
    text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    cut = text.find(" at /")
    return (text[:cut] if cut > 0 else text).rstrip(" .!") or type(exc).__name__


def run_until_stopped(recorder: Recorder, stop: threading.Event, standalone: bool = False) -> RecorderSummary:
    """Start ``recorder`` and block until ``stop`` or its own stop request is set. ``standalone`` (no
    supervisor): say on stderr what it records and where, then its progress every :data:`PROGRESS_S`, and
    stop by itself when the run ends (:meth:`Recorder.follow_run`)."""
    recorder.start()
    opts = recorder.options
    began = time.monotonic()
    if standalone:
        recorder.follow_run()
        print(f"recorder: recording run {opts.run} (everything under {keys.prefix(opts.run)}/) into {opts.out}; "
              "stops on Ctrl-C or once the run has ended", file=sys.stderr, flush=True)
    debug, before, since = Every(log), 0, time.monotonic()
    next_progress, announced = began + PROGRESS_S, None
    try:
        while not (stop.is_set() or recorder.stop_requested.is_set()):
            stop.wait(IDLE_WAKE_S)
            if standalone:
                reason, due = recorder.run_end()
                if reason is not None and reason != announced:
                    announced = reason
                    print(f"recorder: {reason}: finishing once its processes have left (at most "
                          f"{RUN_END_MAX_WAIT_S:g} s)", file=sys.stderr, flush=True)
                if due:
                    recorder.stop_reason = reason or recorder.stop_reason
                    break
                if time.monotonic() >= next_progress:
                    next_progress += PROGRESS_S
                    state = "world alive" if recorder.world_seen else "no world seen yet"
                    print(f"recorder: {recorder.written:,} messages in {time.monotonic() - began:.0f} s "
                          f"(run {opts.run}: {state})", file=sys.stderr, flush=True)
            if debug.due():
                now, written = time.monotonic(), recorder.written
                log.debug("recorder: received and wrote %d messages in %.1f s (%d in all, %d the largest burst)",
                          written - before, now - since, written, recorder._max_backlog)
                before, since = written, now
    finally:
        summary = recorder.stop()
    return summary


@contextlib.contextmanager
def _signals_set(stop: threading.Event, reasons: list[str]):
    """SIGTERM/SIGINT set ``stop`` (main thread only); the old handlers come back afterwards."""

    def handler(signum: int, _frame: object) -> None:
        reasons.append(signal.Signals(signum).name)
        stop.set()

    with signals_handled((signal.SIGTERM, signal.SIGINT), handler):
        yield


def record(options: RecorderOptions, zconfig: Any, summary_json: Optional[str] = None) -> int:
    """Record until SIGINT/SIGTERM/stop command (or the supervisor is gone); print the summary;
    exit code as documented above."""
    stop = threading.Event()
    reasons: list[str] = []
    recorder = Recorder(options, zconfig)

    def supervisor_gone() -> None:  # started by `truav-swarm up`, which was killed: finish the file
        reasons.append("supervisor gone")
        stop.set()

    standalone = watch_supervisor(supervisor_gone) is None
    requests = {}  # SIGHUP splits a recording in parts, SIGUSR1 takes a snapshot (only in those modes)
    if options.modes.split:
        requests[signal.SIGHUP] = CMD_SPLIT
    if options.modes.snapshot is not None:
        requests[signal.SIGUSR1] = CMD_SNAPSHOT

    def on_request(signum: int, _frame: object) -> None:
        recorder.request(requests[signal.Signals(signum)], signal.Signals(signum).name, signalled=True)

    with _signals_set(stop, reasons), signals_handled(tuple(requests), on_request):
        try:
            summary = run_until_stopped(recorder, stop, standalone=standalone)
        except RecorderUsageError as exc:
            print(f"recorder: error: {exc}", file=sys.stderr)
            return EXIT_USAGE
        except Exception as exc:  # zenoh could not open (no router...): one line, no traceback
            print(f"recorder: error: could not record run {options.run}: {short_error(exc)}", file=sys.stderr)
            return EXIT_FAILED
    if reasons and recorder.stop_reason == "stopped":
        summary.stop_reason = reasons[0]
    print(summary.format(), flush=True)
    if summary_json:
        try:
            Path(summary_json).parent.mkdir(parents=True, exist_ok=True)  # checked creatable before the start
            Path(summary_json).write_text(jsonio.dumps(summary.to_json(), indent=1) + "\n")
        except OSError as exc:
            print(f"recorder: error: cannot write {summary_json}: {exc.strerror or exc}", file=sys.stderr)
            return EXIT_FAILED
    return EXIT_FAILED if summary.error else EXIT_OK


# --- for supervisors -----------------------------------------------------------------------
def recorder_argv(run: str, out: str | os.PathLike[str], connect: Sequence[str] = (), *,
                  config_toml: str | os.PathLike[str] | None = None, force: bool = False,
                  geo_origin: tuple[float, float] | None = None, extra: Sequence[str] = (),
                  modes: RecordModes | None = None, python: str = sys.executable,
                  run_info: dict | None = None) -> list[str]:
    """The command line that runs the recorder as a subprocess (see the module docstring): the
    :class:`RecorderOptions` a supervisor sets, as the flags of :mod:`truav.cli.log_process`
    (``config_toml`` here is the file; ``modes``: split or snapshot, their flags as declared in
    :class:`recorder.record_modes.RecordModes`; ``run_info``: the run's settings, RUN_METADATA; ``extra``:
    more flags, e.g. credentials or ``-v``)."""
    argv = [python, "-m", ENTRY_MODULE, "--run", run, "--out", os.fspath(out)]
    if run_info is not None:
        argv += ["--run-info", jsonio.dumps(run_info, sort_keys=True)]
    for endpoint in connect:
        argv += ["--connect", endpoint]
    if config_toml is not None:
        argv += ["--config-toml", os.fspath(config_toml)]
    if geo_origin is not None:
        argv += ["--geo-origin", "%r,%r" % geo_origin]
    if force:
        argv.append("--force")
    if modes is not None:  # the flags given (a default is the recorder's own default too)
        argv += to_argv(modes, [n for n in MODE_FLAGS if getattr(modes, n) != getattr(RecordModes(), n)])
    return argv + list(extra)


def spawn_recorder(run: str, out: str | os.PathLike[str], connect: Sequence[str] = (), *,
                   config_toml: str | os.PathLike[str] | None = None, force: bool = False,
                   geo_origin: tuple[float, float] | None = None, extra: Sequence[str] = (),
                   modes: RecordModes | None = None, **popen_kwargs: Any) -> subprocess.Popen:
    """Start the recorder subprocess (stdout: its summary; pass ``stdout=PIPE`` to capture it).

    The child ignores nothing: stop it with :func:`stop_recorder` (SIGTERM).
    Wait for :func:`wait_until_recording` before publishing what must be recorded.
    """
    popen_kwargs.setdefault("stdin", subprocess.DEVNULL)
    return subprocess.Popen(recorder_argv(run, out, connect, config_toml=config_toml, force=force,
                                          geo_origin=geo_origin, extra=extra, modes=modes), **popen_kwargs)


def wait_until_recording(bus: transport.Bus, run: str, timeout: float = DEFAULT_READY_TIMEOUT_S) -> bool:
    """True once the recorder of ``run`` has declared its liveliness token (it then records
    everything published later); False after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while True:
        left = deadline - time.monotonic()
        if left <= 0:
            return False
        if bus.alive(keys.alive_recorder(run), timeout=min(left, 1.0)):
            return True
        time.sleep(0.05)


def stop_recorder(proc: subprocess.Popen, timeout: float = STOP_GRACE_S) -> int:
    """SIGTERM ``proc`` and wait for it to finish its file; SIGKILL after ``timeout``.
    Returns the exit code (0: file finished)."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            return proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
    return proc.wait()


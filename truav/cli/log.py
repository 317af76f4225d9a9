"""Command-line builders for the recorder tools: recordings under one noun, ``truav log``.

* :func:`add_log_commands` adds to ``truav``::

      truav log record --run RUN --out FILE [-e ENDPOINT] [--config-toml FILE]   # until Ctrl-C / SIGTERM
      truav log play FILE... [--rate R] [--loop] [--topics PAT ...] [--start S] [--duration S] [--paused] [--lockstep]
      truav log report FILE [--out DIR]  # map, metric timelines, agent latency; metrics.csv
      truav log check FILE               # per-sender messages and sequence gaps
      truav log recover IN OUT           # finish an unfinished MCAP (recorder killed)
      truav log record-ctl split|pause|resume|snapshot --run RUN   # a running recorder (truav.cli.log_record_ctl)
      truav log play-ctl --run RUN seek --tick K|rate R|pause|step|status ...   # a running play (truav.cli.swarm_replay)
      truav log cut IN OUT --from-tick A --to-tick B   # a window (truav.cli.log_tools: cut, merge, info)
      truav log merge OUT IN...          # parts, cuts or runs as one
      truav log info FILE...             # per topic, sender and kind; gaps, faults, run metadata
      truav log resim FILE [--from TICK --qtable RUN --greedy --set K=V]  # re-run a lock-step run, check it

  and ``truav report``, an alias of ``truav log report``;
* :func:`add_swarm_commands` adds to ``truav-swarm`` the aliases ``truav-swarm
  record`` (of ``truav log record``) and ``truav-swarm replay`` (of ``truav log play``).

An alias and its ``truav log`` spelling are built by the same function
(:func:`add_record_parser`, :func:`add_play_parser`, :func:`add_report_parser`)
and run the same command; only the one-line help in the parent's list says
"alias of ...", and an error names the program it was typed to.

Every command sets ``func(args) -> exit code`` and reports user mistakes
(missing file, not an MCAP, a pattern matching nothing) in one line on
stderr with exit code 2, never with a traceback.  Heavy imports (mcap,
matplotlib, zenoh) happen inside the commands so ``--help`` stays fast.
"""

from __future__ import annotations

import argparse
import sys
import threading
from pathlib import Path
from typing import Any, Callable

from truav.cli.log_record_ctl import add_record_ctl_parser
from truav.cli.log_tools import add_tool_parsers
from truav.cli.log_resim import add_resim_parser, cmd_resim
from recorder.log_copy import damage_errors, not_mcap_reason
from recorder.mcap_guard import EXIT_DAMAGED, DamagedRecording, damage_line
from truav.cli.args import (check_out_dir, check_out_file, make_dir, non_negative_float, non_negative_int,
                             positive_float)
from truav.errors import UserError

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2
EXIT_PROBLEMS = 1
"""`truav log check`: the recording is unfinished, damaged or has sequence anomalies (like diff/grep, 1 = found)."""


Command = Callable[[argparse.Namespace], int]


def _fail(prog: str, message: str, code: int = EXIT_USAGE) -> int:
    print(f"{prog}: error: {message}", file=sys.stderr)
    return code


def _mcap_file(path: str) -> str | None:
    """An error message when ``path`` is not a readable MCAP file, else None."""
    return not_mcap_reason(path)


# --- truav log recover / check, truav report --------------------------------------------------
def cmd_log_recover(args: argparse.Namespace) -> int:
    from recorder.recover import recover

    problem = _mcap_file(args.input)
    if problem:
        return _fail("truav", problem)
    if Path(args.output).resolve() == Path(args.input).resolve():
        return _fail("truav", "OUT must differ from IN (the damaged file is kept as evidence)")
    if Path(args.output).exists() and not args.force:
        return _fail("truav", f"{args.output} exists; use --force to overwrite it")
    try:
        check_out_file("OUT", args.output)
        make_dir("OUT", Path(args.output).parent)  # a new directory, as cut and merge make it
    except ValueError as exc:
        return _fail("truav", str(exc))
    try:
        rep = recover(args.input, args.output, compression=args.compression)
    except OSError as exc:
        return _fail("truav", f"recovery failed: {exc.strerror or exc}", EXIT_FAILED)
    if rep.messages == 0:  # an empty "recovered" file would pass for a real one (header-only input included)
        Path(args.output).unlink(missing_ok=True)
        why = (f"no message; {rep.corrupt_chunks} corrupt chunk(s), {rep.invalid_records} invalid record(s), "
               f"{rep.torn_bytes:,} torn bytes" + (f"; stopped early: {rep.error}" if rep.error else ""))
        return _fail("truav", f"{args.input}: nothing salvageable ({why}); {args.output} not written", EXIT_FAILED)
    span = ((rep.last_log_time - rep.first_log_time) / 1e9
            if rep.first_log_time is not None and rep.last_log_time is not None else 0.0)
    state = "unfinished (writer died)" if rep.truncated else "already finished (re-chunked copy)"
    print(f"{rep.in_path}: {state}, {rep.input_bytes:,} bytes, {rep.torn_bytes:,} torn bytes dropped")
    print(f"{rep.out_path}: {rep.messages} messages over {span:.3f} s on {rep.channels} channels, "
          f"{rep.metadata} metadata, {rep.attachments} attachments")
    if not rep.clean:  # what was left out, and the exit code says it (OUT carries a truav.damage record)
        return _fail("truav", f"{args.input}: damaged recording, left out of {args.output}: {rep.corrupt_chunks} "
                              f"corrupt chunk(s), {rep.invalid_records} invalid record(s)"
                              + (f"; stopped early: {rep.error}" if rep.error else "")
                              + (f" ({'; '.join(rep.notes)})" if rep.notes else ""), EXIT_DAMAGED)
    return EXIT_OK


def cmd_log_check(args: argparse.Namespace) -> int:
    from recorder.check import check

    problem = _mcap_file(args.file)
    if problem:
        return _fail("truav", problem)
    report = check(args.file)
    print(report.format_report(max_ranges=args.max_ranges), flush=True)
    if report.problems:
        print(f"truav log check: {args.file}: {'; '.join(report.problems)}", file=sys.stderr)
        return EXIT_PROBLEMS
    return EXIT_OK


def cmd_report(args: argparse.Namespace) -> int:
    from recorder.check import check
    from recorder.report import ReportError, report

    problem = _mcap_file(args.file)
    if problem:
        return _fail("truav", problem)
    audit = check(args.file)  # a damaged chunk would stop the report halfway: say so first
    if audit.damaged:
        return _fail("truav", f"{args.file}: damaged recording ({'; '.join(audit.problems[:3])}); "
                              f"`truav log recover {args.file} FIXED.mcap` salvages the rest", EXIT_DAMAGED)
    if audit.messages == 0:  # a report of nothing would look like a run where nothing happened
        return _fail("truav", f"{args.file}: no bus messages in the file; nothing to report", EXIT_FAILED)
    if args.out is not None:
        try:
            check_out_dir("--out", args.out)
        except ValueError as exc:
            return _fail("truav", str(exc))
    try:
        _, lines = report(args.file, args.out)
    except ReportError as exc:
        return _fail("truav", str(exc))
    except damage_errors() as exc:
        return _fail("truav", damage_line(args.file, exc), EXIT_DAMAGED)
    except OSError as exc:
        return _fail("truav", f"cannot write the report: {exc.strerror or exc}", EXIT_FAILED)
    print("\n".join(lines))
    return EXIT_OK


# --- truav log record / play (aliases truav-swarm record / replay) ---------------------------------
def cmd_record(args: argparse.Namespace, prog: str = "truav-swarm") -> int:
    import math

    from truav.cli.log_process import cmd_record as run_record

    # The flags truav.cli.log_process leaves to later (a NaN there reaches int() mid-start).
    for flag, value, positive in (("--flush-ms", args.flush_ms, True), ("--router-wait", args.router_wait, False)):
        if not math.isfinite(value) or value < 0 or (positive and value == 0):
            return _fail(prog, f"{flag}: must be a finite number {'>' if positive else '>='} 0, got {value}")
    try:
        check_out_file("--out", args.out)
        if args.summary_json is not None:
            _check_summary_json(args.summary_json, args.out)
    except ValueError as exc:
        return _fail(prog, str(exc))
    if args.config_toml is not None:
        from truav.config import ConfigError, read_toml
        try:
            read_toml(args.config_toml, "--config-toml", ConfigError)
        except ConfigError as exc:
            return _fail(prog, str(exc))
    return run_record(args)


def _check_summary_json(path: str, out: str) -> None:
    """--summary-json: a file that can be written at the end (found out now, not after the recording),
    and none of the recording's own files, which it would overwrite."""
    from recorder.record_modes import parts_index_path

    check_out_file("--summary-json", path)
    if Path(path).resolve() in (Path(out).resolve(), parts_index_path(Path(out)).resolve()):
        raise UserError(f"--summary-json {path}: is a file of the recording itself (--out {out}); give another "
                        f"name, such as {Path(out).with_suffix('.summary.json')}")


def cmd_replay(args: argparse.Namespace, prog: str = "truav-swarm") -> int:
    import signal

    from recorder.replay import (CONTROL_PART, KEYS_HELP, KeyboardControl, Replayer, ReplayOptions,
                                 ReplayUsageError, recording_info, split_patterns)
    from recorder.process.replay_bus import replay_on_bus
    from truav.bus.transport import config_from_args
    from truav.bus.zenoh_config import apply_replay_creds
    from truav.wire import keys

    for name in args.file:
        problem = None if name.endswith(".parts.json") and Path(name).is_file() else _mcap_file(name)
        if problem and not (len(args.file) == 1 and _parts_index_beside(name)):
            return _fail(prog, problem)
    try:
        apply_replay_creds(args, keys.SRC_REPLAY)  # under --creds: into <run>-replay, the only run it may use
        include, exclude = split_patterns(args.topics, args.exclude)
        options = ReplayOptions(path=tuple(Path(f) for f in args.file), run=args.run, rate=args.rate,
                                loops=None if args.loop else 1, include=include, exclude=exclude,
                                start_s=args.start, duration_s=args.duration, paused=args.paused,
                                with_control=args.with_control, lockstep=args.lockstep,
                                lockstep_wait_s=args.lockstep_wait)
        zconfig = config_from_args(args)
        info = recording_info(options.path)  # the parts resolved: each is checked below
    except DamagedRecording as exc:
        return _fail(prog, str(exc), EXIT_DAMAGED)
    except (ReplayUsageError, ValueError) as exc:
        return _fail(prog, str(exc))
    from recorder.check import check
    for part in info.paths:
        audit = check(part)  # a damaged chunk would stop the replay halfway: say so first
        if audit.damaged:
            return _fail(prog, f"{part}: damaged recording ({'; '.join(audit.problems[:3])}); "
                               f"`truav log recover {part} FIXED.mcap` salvages the rest", EXIT_DAMAGED)
    try:  # the patterns against the recorded keys, before the banner (replay_on_bus checks again)
        target = Replayer(options, lambda _key, _payload: None, info).target_run
        if target is None:
            return _fail(prog, f"{args.file[0]}: no truav/<run>/ keys to replay")
    except ReplayUsageError as exc:
        return _fail(prog, str(exc))
    except damage_errors() as exc:
        return _fail(prog, damage_line(args.file[0], exc), EXIT_DAMAGED)
    keyboard = KeyboardControl.available() and not args.no_keys
    stop = threading.Event()
    quiet = args.quiet

    def on_state(command: str) -> None:  # from several threads (keys, bus, the replay): one write per line
        if not quiet:
            sys.stderr.write(f"replay: {command}\n")
            sys.stderr.flush()

    previous = {}
    if threading.current_thread() is threading.main_thread():  # signal handlers only work there
        previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        if not quiet:
            hint = f"keys: {KEYS_HELP}; " if keyboard else ""
            recorded = ", ".join(repr(r) for r in info.runs)
            runs = f"run {recorded}" if list(info.runs) == [target] else f"recorded run(s) {recorded} as {target!r}"
            files = args.file[0] if len(info.paths) == 1 else f"{len(info.paths)} parts of {args.file[0]}"
            print(f"replay: {files} ({runs}){' (paused)' if args.paused else ''}"
                  f"{' (lock-step with the live agents)' if args.lockstep else ''}; {hint}status on "
                  f"{keys.replay_status(target)}; `truav-swarm replay-ctl --run {target} ...` or bus commands on "
                  f"{keys.control(target, CONTROL_PART)}", file=sys.stderr, flush=True)
        stats = replay_on_bus(options, zconfig, keyboard=keyboard, stop=stop, on_state=on_state)
    except ReplayUsageError as exc:
        return _fail(prog, str(exc))
    except Exception as exc:  # zenoh could not open (no router...): one line
        from recorder.process.recorder import short_error

        return _fail(prog, f"replay failed: {short_error(exc)}", EXIT_FAILED)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    print(stats.format())
    if stats.lockstep_given_up:  # not paced by every live agent throughout: say so in the exit code too
        return _fail(prog, f"--lockstep: {stats.lockstep_given_up} answer(s) of live agents not received within "
                           f"--lockstep-wait {args.lockstep_wait:g} s", EXIT_FAILED)
    return EXIT_OK


def _parts_index_beside(name: str) -> bool:
    """``<stem>.mcap`` that a split recording never wrote, its ``<stem>.parts.json`` beside it."""
    from recorder.replay_source import index_beside
    return index_beside(Path(name)) is not None


REPLAY_EXAMPLE = ("Example, one live agent driven by a recorded world (a live agent drops replayed traffic "
                  "unless given --accept-replay): `truav-swarm agent --id 3 --run demo --accept-replay "
                  "-e tcp/127.0.0.1:7447`, then `truav-swarm replay runs/demo.mcap -e tcp/127.0.0.1:7447 "
                  "--topics 'truav/*/world/tick' 'truav/*/uav/3/obs'`.")
"""`replay --help`'s example (tests/swarm/test_replay.py parses its commands with the real parsers)."""




# --- the parsers, each built by one function (the `truav log` spelling and its alias share it) ----------
RECORD_HELP = "record every message of a run into an MCAP file (until the run ends, or Ctrl-C)"
PLAY_HELP = "re-publish a recording onto Zenoh with its original timing"
REPORT_HELP = "pictures of a recorded run: map, metric timelines, agent latency; metrics.csv"


def alias_help(new: str) -> str:
    """The one-line help of an old spelling in its parent's command list."""
    return f"alias of `{new}`"


def add_record_parser(subparsers: Any, help: str) -> argparse.ArgumentParser:
    """``record``: the recorder process's flags (:func:`truav.cli.log_process.add_record_args`)."""
    from truav.cli.log_process import add_record_args

    rec = subparsers.add_parser(
        "record", help=help,
        description="Record every message under truav/<run>/ into an MCAP file: one channel per key "
                    "(msgpack, with a JSON Schema), JSON mirrors of beacons, positions and metrics for "
                    "Foxglove, the run config as metadata. Stops on Ctrl-C, SIGTERM, a 'stop' control "
                    "message on truav/<run>/control/recorder or, started alone (not by `up`), once the run has "
                    "ended (the world's shutdown, or the world gone) and its processes have left; says on stderr "
                    "what it records, where, and its progress; finishes the file and prints a summary.")
    add_record_args(rec)
    return rec


def add_play_parser(subparsers: Any, name: str, help: str) -> argparse.ArgumentParser:
    """``play`` (``truav log``) or ``replay`` (``truav-swarm``): re-publish a recording."""
    from recorder.replay import KEYS_HELP
    from truav.cli.args import add_transport_args

    rp = subparsers.add_parser(
        name, help=help,
        description="Re-publish a recording's payloads unchanged, with the recorded timing. "
                    f"Keys (on a terminal): {KEYS_HELP}. From another terminal: truav-swarm replay-ctl --run RUN "
                    "seek --tick 40|rate 2|pause|resume|step|burst 5|status (over the queryable "
                    "truav/<run>/replay/ctl), or a control message on truav/<run>/control/replay with command "
                    "pause|resume|toggle|step|burst|next|seek|rate|quit. A seek (to a time, a tick, or back/forward "
                    "by a time) first sends each channel's last message before that point. Status about 5 times a "
                    f"second on truav/<run>/replay/status. {REPLAY_EXAMPLE}",
        epilog="Exit codes: 0 played; 1 a damaged recording (refused before anything is published; see "
               "docs/reference/untrusted-recordings.md), the bus failed, or --lockstep gave up waiting; 2 a user mistake.")
    rp.add_argument("file", metavar="FILE", nargs="+",
                    help="MCAP recording (finished or not); a split recording: its <stem>.parts.json, any part, "
                         "or all its parts (played as one, in part order)")
    rp.add_argument("--rate", type=positive_float, default=1.0, help="speed factor (default 1.0; 2 = twice as fast)")
    rp.add_argument("--loop", action="store_true", help="start over at the end, until q / Ctrl-C")
    rp.add_argument("--topics", nargs="+", default=[], metavar="PATTERN",
                    help="replay only keys matching these globs (* also matches /); !PATTERN excludes")
    rp.add_argument("--exclude", nargs="+", default=[], metavar="PATTERN", help="skip keys matching these globs")
    rp.add_argument("--start", type=non_negative_float, default=0.0, metavar="S",
                    help="skip the first S seconds of the recording")
    rp.add_argument("--duration", type=positive_float, default=None, metavar="S", help="replay only S seconds")
    rp.add_argument("--paused", action="store_true", help="start paused (then: space/s, or bus commands)")
    rp.add_argument("--run", metavar="NEW", help="publish under truav/NEW/ instead of the recorded run")
    rp.add_argument("--with-control", action="store_true",
                    help="also replay recorded control messages (skipped by default: old stop/shutdown "
                         "commands would hit live processes)")
    rp.add_argument("--lockstep", action="store_true",
                    help="consumer-paced: send the recorded tick k only once the live agents sent an observation "
                         "of tick k-1 answered it (their actions; recorded actions are not replayed), as fast as "
                         "they answer")
    rp.add_argument("--lockstep-wait", type=positive_float, default=60.0, metavar="S",
                    help="--lockstep: how long to wait for a live agent's answer before going on without it "
                         "(default 60)")
    rp.add_argument("--no-keys", action="store_true", help="ignore the keyboard even on a terminal")
    rp.add_argument("--quiet", action="store_true", help="print only the final summary")
    add_transport_args(rp)
    return rp


def add_report_parser(subparsers: Any, help: str) -> argparse.ArgumentParser:
    rep = subparsers.add_parser(
        "report", help=help,
        description="Write map.png (roads, RSUs, vehicle density, UAV tracks, coverage), metrics.png (step "
                    "metrics over time, faults shaded), agents.png (beacon rate and one-way latency per agent), "
                    "links.png (beacon delivery per link, sender x receiver, from the agents' own counts) "
                    "and metrics.csv from a recording.",
        epilog="Exit codes: 0 written; 1 a damaged recording (refused; see docs/reference/untrusted-recordings.md), no message, or "
               "writing failed; 2 a user mistake (missing or non-MCAP file, --out under a file).")
    rep.add_argument("file", metavar="FILE", help="MCAP recording (finished or not)")
    rep.add_argument("--out", metavar="DIR", help="output directory (default: <FILE stem>_report next to FILE)")
    return rep


def _check_endpoints(args: argparse.Namespace) -> None:
    """What ``truav-swarm``'s main checks before any command (``truav log record|play`` run under
    ``truav``'s main): the same check, so the same mistakes get the same one line."""
    from truav.cli.args import check_transport
    check_transport(args)


def cmd_log_record(args: argparse.Namespace) -> int:
    """``truav log record``: ``truav-swarm record``'s command, its errors named ``truav``."""
    _check_endpoints(args)
    return cmd_record(args, prog="truav")


def cmd_log_play(args: argparse.Namespace) -> int:
    """``truav log play``: ``truav-swarm replay``'s command, its errors named ``truav``."""
    _check_endpoints(args)
    return cmd_replay(args, prog="truav")


def cmd_log_play_ctl(args: argparse.Namespace) -> int:
    """``truav log play-ctl``: ``truav-swarm replay-ctl``'s command, its endpoints checked as there."""
    from truav.cli.swarm_replay import cmd_replay_ctl
    _check_endpoints(args)
    return cmd_replay_ctl(args)


# --- the command groups ---------------------------------------------------------------------------
def add_log_commands(subparsers: Any) -> None:
    """Add ``log record|play|report|check|recover|cut|merge|info|resim`` (and the record-ctl / play-ctl
    commands) to the ``truav`` CLI, and ``report``, an alias of ``log report``."""
    log = subparsers.add_parser("log", help="record, play, report on, check, repair, cut, merge, describe and "
                                            "re-simulate MCAP recordings of swarm runs",
                                description="Record, play, report on, check, repair, cut, merge, describe and "
                                            "re-simulate MCAP recordings made by the TRUAV recorder.")
    log_sub = log.add_subparsers(dest="log_command", required=True, metavar="ACTION")
    add_record_parser(log_sub, RECORD_HELP).set_defaults(func=cmd_log_record)
    add_play_parser(log_sub, "play", PLAY_HELP).set_defaults(func=cmd_log_play)
    add_report_parser(log_sub, REPORT_HELP).set_defaults(func=cmd_report)
    add_resim_parser(log_sub).set_defaults(func=cmd_resim)

    rec = log_sub.add_parser(
        "recover", help="finish an unfinished recording (recorder killed) into a valid MCAP file",
        description="Salvage every complete chunk of IN (a recording whose recorder died, so it has no "
                    "summary and mcap's make_reader cannot open it) into a finished MCAP file OUT. "
                    "A recorder flushes a chunk at least every 50 ms, so about that much is lost.",
        epilog="Exit codes: 0 written, nothing lost but a torn tail; 1 damage left out (corrupt chunks, invalid "
               "records: named on stderr; OUT carries a truav.damage record, so `truav log check OUT` is not "
               "clean), no message to salvage, or writing failed; 2 a user mistake (missing or non-MCAP file, OUT "
               "exists...). See docs/reference/untrusted-recordings.md.")
    rec.add_argument("input", metavar="IN", help="the unfinished (or any) MCAP file; left untouched")
    rec.add_argument("output", metavar="OUT", help="the finished MCAP file to write")
    rec.add_argument("--compression", choices=["zstd", "lz4", "none"], default="zstd",
                     help="chunk compression of OUT (default zstd)")
    rec.add_argument("--force", action="store_true", help="overwrite OUT if it exists")
    rec.set_defaults(func=cmd_log_recover)

    chk = log_sub.add_parser(
        "check", help="per sender: messages present and sequence gaps (what the bus lost)",
        description="Audit a recording. Every sender numbers its messages per kind, so a gap in one "
                    "sender's sequence numbers is a message that never reached the recorder (lost on the bus "
                    "or sent before it subscribed); an UNFINISHED file means the recorder itself died and "
                    "lost its last flush interval (run `truav log recover`). Exit code 0: finished and "
                    "complete; 1: unfinished, damaged, or with gaps, duplicates, reordering or undecodable "
                    "messages (listed on stderr), a damaged file (corrupt chunks, records over the caps, invalid "
                    "schemas, channels or messages: left out and named), or one written from a damaged file (a "
                    "truav.damage record); 2: not an MCAP file. See docs/reference/untrusted-recordings.md.")
    chk.add_argument("file", metavar="FILE", help="MCAP recording (finished or not)")
    chk.add_argument("--max-ranges", type=non_negative_int, default=4, metavar="N", help="gap ranges shown per sender (default 4)")
    chk.set_defaults(func=cmd_log_check)
    add_tool_parsers(log_sub)

    add_record_ctl_parser(log_sub)
    from truav.cli.swarm_replay import add_replay_ctl  # the same command as truav-swarm replay-ctl
    add_replay_ctl(log_sub, "play-ctl", "truav log play-ctl", "steer a running play (seek, rate, pause, step by tick...) "
                                                             "and print its status").set_defaults(func=cmd_log_play_ctl)

    add_report_parser(subparsers, alias_help("truav log report")).set_defaults(func=cmd_report)


def add_swarm_commands(subparsers: Any) -> None:
    """Add ``record`` and ``replay`` to the ``truav-swarm`` CLI: aliases of ``truav log record|play``."""
    add_record_parser(subparsers, alias_help("truav log record")).set_defaults(func=cmd_record)
    add_play_parser(subparsers, "replay", alias_help("truav log play")).set_defaults(func=cmd_replay)

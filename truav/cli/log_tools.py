"""``truav log cut|merge|info``: the parsers and commands of the recording tools (added to ``truav log``
by :func:`truav.cli.log.add_log_commands`)::

    truav log cut IN OUT [--start S] [--end S] [--start-ns NS] [--end-ns NS] [--from-tick A] [--to-tick B]
                         [--topics PAT ...] [--exclude PAT ...] [--force]
    truav log merge OUT IN... [--force]
    truav log info FILE... [--json]
    truav log ros2bag RECORDING --out BAG [--force]

A user mistake (IN not an MCAP file or unfinished, OUT existing without --force, a contradictory or
empty window, a pattern matching nothing) is one line on stderr and exit 2, before anything is
written; OUT is written to ``OUT.part`` and renamed when complete. A damaged input (a chunk failing
its CRC, a record declaring more than the caps, an invalid schema, channel or message; see
recorder.mcap_guard) is exit 1: cut and merge write what is sound, say on stderr what they left out
and mark OUT with a ``truav.damage`` record (so `truav log check OUT` does not call it clean); info
prints what it could read and names the damage.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any, Optional

from recorder.mcap_guard import EXIT_DAMAGED
from truav.cli.args import non_negative_float, non_negative_int
from truav.errors import EXIT_USAGE, UserError
from truav import jsonio

EXIT_OK, EXIT_FAILED = 0, 1
PROG = "truav"
DAMAGE_EPILOG = ("Exit codes: 0 done; 1 an input is damaged (corrupt chunk, a record over the caps, an invalid "
                 "schema, channel or message: what was left out is said on stderr, and OUT carries a truav.damage "
                 "record) or writing failed; 2 a user mistake (missing or non-MCAP file, unfinished input, OUT "
                 "exists...). See docs/reference/untrusted-recordings.md.")


def _fail(message: str, code: int = EXIT_USAGE) -> int:
    print(f"{PROG}: error: {message}", file=sys.stderr)
    return code


def _damage_errors() -> tuple[type[BaseException], ...]:
    from recorder.log_copy import damage_errors
    return damage_errors()


def _damage_line(path: str, exc: BaseException) -> str:
    from recorder.mcap_guard import damage_line
    return damage_line(path, exc)


def _check_out(out: str, inputs: list[str], force: bool) -> None:
    from truav.checks import check_out_file

    check_out_file("OUT", out)
    for path in inputs:
        if Path(path).resolve() == Path(out).resolve():
            raise UserError(f"OUT {out}: is also an input (the input is kept as it is)")
    if Path(out).exists() and not force:
        raise UserError(f"OUT {out}: exists; use --force to overwrite it")


def _seconds(ns: Optional[int], origin: Optional[int]) -> str:
    return "-" if ns is None or origin is None else f"{(ns - origin) / 1e9:.3f}"


def _split_patterns(topics: list[str], exclude: list[str]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """``--topics`` entries starting with ``!`` are excludes, as in replay's ``--topics``; returns (include, exclude)."""
    from recorder.replay_setup import ReplayUsageError, split_patterns
    try:
        return split_patterns(topics, exclude)
    except ReplayUsageError as exc:
        raise UserError(f"--topics/--exclude: {exc}") from None


# --- truav log cut ----------------------------------------------------------------------------------
def cmd_log_cut(args: argparse.Namespace) -> int:
    from recorder.cut import WindowSpec, cut
    from recorder.log_copy import not_mcap_reason

    problem = not_mcap_reason(args.input)
    if problem:
        return _fail(f"IN {problem}")
    try:
        include, exclude = _split_patterns(args.topics, args.exclude)
        _check_out(args.output, [args.input], args.force)
        spec = WindowSpec(start_s=args.start, end_s=args.end, start_ns=args.start_ns, end_ns=args.end_ns,
                          from_tick=args.from_tick, to_tick=args.to_tick)
        report = cut(args.input, args.output, spec, include, exclude)
    except UserError as exc:
        return _fail(str(exc))
    except _damage_errors() as exc:
        return _fail(f"IN {_damage_line(args.input, exc)}", EXIT_DAMAGED)
    except OSError as exc:
        return _fail(f"cut failed: {exc.strerror or exc}", EXIT_FAILED)
    origin = report.source_first_log_time
    print(f"{report.out_path}: {report.messages:,} messages of {report.in_path} at {_seconds(report.first_log_time, origin)}"
          f"..{_seconds(report.last_log_time, origin)} s of it, {report.kept} last-before messages kept at the "
          f"window's start, {report.channels} channels, metadata {', '.join(report.metadata) or 'none'} + truav.cut")
    if report.damage.damaged:
        return _fail(f"IN {args.input}: damaged recording, left out of {args.output}: {report.damage.describe()}; "
                     f"{args.output} is marked truav.damage", EXIT_DAMAGED)
    return EXIT_OK


# --- truav log merge --------------------------------------------------------------------------------
def cmd_log_merge(args: argparse.Namespace) -> int:
    from recorder.log_copy import not_mcap_reason
    from recorder.merge import PARTS_INDEX_SUFFIX, merge

    for path in args.inputs:
        problem = None if path.endswith(PARTS_INDEX_SUFFIX) else not_mcap_reason(path)
        if problem:
            return _fail(f"IN {problem}")
    try:
        _check_out(args.output, args.inputs, args.force)
        report = merge(args.output, args.inputs)
    except UserError as exc:
        return _fail(str(exc))
    except _damage_errors() as exc:
        return _fail(f"IN {_damage_line('(one of them)', exc)}", EXIT_DAMAGED)
    except OSError as exc:
        return _fail(f"merge failed: {exc.strerror or exc}", EXIT_FAILED)
    span = _seconds(report.last_log_time, report.first_log_time)
    print(f"{report.out_path}: {report.messages:,} messages over {span} s on {report.channels} channels from "
          f"{len(report.inputs)} files ({', '.join(i.path.name for i in report.inputs)}), "
          f"{report.duplicates:,} duplicates dropped, {report.restored} cut-kept messages back at their log times, "
          f"{report.metadata} metadata records")
    for session, parts in report.missing_parts.items():
        print(f"truav log merge: session {session}: part(s) {', '.join(map(str, parts))} not given "
              f"(the merged run has a hole there)", file=sys.stderr)
    for name, damage in report.damaged.items():
        print(f"{PROG}: error: IN {name}: damaged recording, left out of {args.output}: {damage.describe()}",
              file=sys.stderr)
    if report.damaged:
        return EXIT_DAMAGED
    return EXIT_OK


# --- truav log info ---------------------------------------------------------------------------------
def cmd_log_info(args: argparse.Namespace) -> int:
    from recorder.info import info
    from recorder.log_copy import not_mcap_reason

    for path in args.files:
        problem = not_mcap_reason(path)
        if problem:
            return _fail(problem)
    results = []
    for path in args.files:
        try:
            results.append(info(path))
        except _damage_errors() as exc:
            return _fail(_damage_line(path, exc), EXIT_DAMAGED)
    if args.json:
        print(jsonio.dumps([r.as_json() for r in results], indent=1))
    else:
        print("\n\n".join(r.format() for r in results))
    damaged = [r for r in results if r.damage.damaged]
    for r in damaged:
        print(f"{PROG}: error: {r.path}: damaged recording (the counts above are of what was sound): "
              f"{r.damage.describe()}",
              file=sys.stderr)
    return EXIT_DAMAGED if damaged else EXIT_OK


# --- truav log ros2bag ------------------------------------------------------------------------------
def cmd_log_ros2bag(args: argparse.Namespace) -> int:
    from recorder.log_copy import not_mcap_reason
    from recorder.ros2_export import Ros2Unavailable, export, is_bag

    problem = not_mcap_reason(args.recording)
    if problem:
        return _fail(f"RECORDING {problem}")
    out = Path(args.out)
    if out.exists() and not args.force:
        return _fail(f"--out {out}: exists; use --force to replace it")
    if out.exists() and not (is_bag(out) or out.is_file()):
        return _fail(f"--out {out}: is a directory but not a ROS 2 bag (no metadata.yaml); not replaced")
    if not out.parent.is_dir():
        return _fail(f"--out {out}: no directory {out.parent}")
    try:
        report = export(Path(args.recording), out, replace=args.force)
    except Ros2Unavailable as exc:
        return _fail(f"ros2bag {exc}")
    except _damage_errors() as exc:
        return _fail(f"RECORDING {_damage_line(args.recording, exc)}", EXIT_DAMAGED)
    except OSError as exc:
        return _fail(f"ros2bag failed: {exc.strerror or exc}", EXIT_FAILED)
    poses = sum(n for topic, n in report.messages.items() if topic.endswith("/pose"))
    print(f"{out}: ROS 2 bag (MCAP, CDR) of {args.recording}: {report.total:,} messages, {poses:,} poses of "
          f"{sum(t.endswith('/pose') for t in report.messages)} UAVs, {report.messages['/truav/markers']:,} marker "
          f"arrays, {report.messages['/truav/metrics']:,} diagnostics"
          + (f"; {report.undecodable:,} undecodable payloads left out" if report.undecodable else ""))
    return EXIT_OK


# --- the parsers ----------------------------------------------------------------------------------------
def add_tool_parsers(log_sub: Any) -> None:
    """``cut``, ``merge`` and ``info`` under ``truav log``."""
    cut = log_sub.add_parser(
        "cut", help="a time or tick window of a recording (and chosen topics) as a recording of its own",
        description="Write the messages of IN in a window of log time to OUT: by time (--start/--end seconds "
                    "from IN's first message, or --start-ns/--end-ns absolute), or by tick (--from-tick A "
                    "--to-tick B: from world tick A's message to the next tick message after B, so tick B's "
                    "answers stay in). The last message of every chosen channel before the window is kept, "
                    "stamped at the window's start (a replay or a late joiner starts with the state then; the "
                    "truav.cut metadata record lists them with their original log times, which `truav log "
                    "merge` restores). IN's metadata is kept. IN must be finished (`truav log recover` first).",
        epilog=DAMAGE_EPILOG)
    cut.add_argument("input", metavar="IN", help="a finished MCAP recording; left untouched")
    cut.add_argument("output", metavar="OUT", help="the MCAP file to write")
    cut.add_argument("--start", type=non_negative_float, metavar="S", help="window start, seconds from IN's first message")
    cut.add_argument("--end", type=non_negative_float, metavar="S", help="window end (exclusive), seconds from IN's first message")
    cut.add_argument("--start-ns", type=non_negative_int, metavar="NS", help="window start, absolute log time (ns)")
    cut.add_argument("--end-ns", type=non_negative_int, metavar="NS", help="window end (exclusive), absolute log time (ns)")
    cut.add_argument("--from-tick", type=non_negative_int, metavar="A", help="window from world tick A")
    cut.add_argument("--to-tick", type=non_negative_int, metavar="B", help="window to the end of world tick B")
    cut.add_argument("--topics", nargs="+", default=[], metavar="PATTERN",
                     help="keep only keys matching these globs (* also matches /); !PATTERN excludes")
    cut.add_argument("--exclude", nargs="+", default=[], metavar="PATTERN", help="drop keys matching these globs")
    cut.add_argument("--force", action="store_true", help="overwrite OUT if it exists")
    cut.set_defaults(func=cmd_log_cut)

    mrg = log_sub.add_parser(
        "merge", help="recordings (parts of a split run, cuts, runs) as one, in log-time order",
        description="Write every message of the inputs to OUT in log-time order, schemas and channels once, "
                    "a message found in several inputs (same topic, log time, publish time and bytes) once. "
                    "Parts of a split recording (truav.part records, or a <stem>.parts.json index given as an "
                    "input) are joined in part order; a cut's kept last-before messages get their original "
                    "log times back, so the cuts of a recording merge back into it. Metadata is kept; a "
                    "truav.merge record lists the inputs.", epilog=DAMAGE_EPILOG)
    mrg.add_argument("output", metavar="OUT", help="the MCAP file to write")
    mrg.add_argument("inputs", nargs="+", metavar="IN", help="finished MCAP recordings, or <stem>.parts.json indexes")
    mrg.add_argument("--force", action="store_true", help="overwrite OUT if it exists")
    mrg.set_defaults(func=cmd_log_merge)

    inf = log_sub.add_parser(
        "info", help="what a recording holds: per topic, sender and kind; gaps, faults, run metadata",
        description="Per topic, per sender (the envelope's src) and per kind: messages, first/last time (s "
                    "from the file's first message) and mean rate; sequence gaps per sender; fault windows; "
                    "the world's tick range; the run's metadata (run, seed, scheme, split part, cut window, "
                    "merge inputs). Works on unfinished files too.",
        epilog="Exit codes: 0 done; 1 a file is damaged (what was left out is named on stderr); 2 a missing or "
               "non-MCAP file. See docs/reference/untrusted-recordings.md.")
    inf.add_argument("files", nargs="+", metavar="FILE", help="MCAP recordings")
    inf.add_argument("--json", action="store_true", help="print a JSON list, one object per file")
    inf.set_defaults(func=cmd_log_info)

    bag = log_sub.add_parser(
        "ros2bag", help="a recording's poses, markers and metrics as a ROS 2 bag (ros2 bag play, RViz)",
        description="Write RECORDING as a ROS 2 bag directory BAG (rosbag2 format 9, MCAP storage, CDR messages "
                    "with ros2msg schemas, ROS 2 Jazzy's types): /truav/uav_<i>/pose (geometry_msgs/msg/PoseStamped, "
                    "frame map, x east y north in m, z the scenario's UAV altitude) for every observation, "
                    "/truav/markers (visualization_msgs/msg/MarkerArray: UAVs, vehicles, RSUs) for every positions "
                    "message, /truav/metrics (diagnostic_msgs/msg/DiagnosticArray: the world's step and episode "
                    "metrics, each UAV's energy per step). Stamps are the recording's log times. Needs the ros2 "
                    "extra (pip install -e '.[ros2]'). See docs/how-to/ros2.md.",
        epilog="Exit codes: 0 written; 1 RECORDING is damaged (nothing is written; `truav log recover` keeps what is "
               "sound) or writing failed; 2 a user mistake (missing or non-MCAP file, BAG exists without --force, "
               "the ros2 extra not installed). See docs/reference/untrusted-recordings.md.")
    bag.add_argument("recording", metavar="RECORDING", help="an MCAP recording of a swarm run")
    bag.add_argument("--out", required=True, metavar="BAG", help="the bag directory to write")
    bag.add_argument("--force", action="store_true", help="replace BAG (a bag directory or a file) if it exists")
    bag.set_defaults(func=cmd_log_ros2bag)

"""The recorder process's command line: ``python -m truav.cli.log_process --run RUN --out FILE ...``.

:func:`add_record_args` declares the recorder's flags (shared with ``truav log
record`` and ``truav-swarm record``, see :mod:`truav.cli.log`);
:func:`options_from_args` turns them into the :class:`recorder.process.recorder.RecorderOptions`
the node runs with, and :func:`cmd_record` runs it.  ``recorder.process.recorder.recorder_argv``
builds this command line for supervisors; ``python -m recorder.process`` (the
old spelling) hands over to :func:`main`.  The recording node itself is
imported when a command runs, so building the parser (``truav --help``) does
not load mcap's reader, zstd and the recovery code.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any, Optional

from recorder.foxglove import DEFAULT_ORIGIN, parse_origin
from recorder.mcap_writer import COMPRESSIONS, DEFAULT_COMPRESSION, DEFAULT_FLUSH_INTERVAL_S
from recorder.record_modes import RecordModes
from truav.bus import transport
from truav.cli import args as cli_args
from truav.wire import keys

if TYPE_CHECKING:
    from recorder.process.recorder import RecorderOptions

__all__ = ["add_record_args", "options_from_args", "zenoh_config_from_args", "cmd_record", "main"]

DEFAULT_ROUTER_WAIT_S = 10.0  # a client waits this long for the router (it may start after us)


def zenoh_config_from_args(args: argparse.Namespace) -> Any:
    """Like :func:`transport.config_from_args`, plus a client wait for the router
    (``--router-wait``), so a supervisor may start us before the router is up."""
    mode = args.mode if args.mode is not None else (None if args.config else transport.MODE_CLIENT)
    wait_ms = int(args.router_wait * 1000) if mode == transport.MODE_CLIENT else None
    return transport.make_config(mode, args.connect or (), args.listen or (), args.config,
                                 connect_timeout_ms=wait_ms)


def options_from_args(args: argparse.Namespace) -> RecorderOptions:
    from recorder.process.recorder import RecorderOptions, RecorderUsageError  # the node: mcap, zstd, foxglove

    toml_text = None
    if args.config_toml:
        path = Path(args.config_toml)
        if not path.is_file():
            raise RecorderUsageError(f"config file not found: {path}")
        toml_text = path.read_text(encoding="utf-8")
    run_info = None
    if args.run_info:
        try:
            run_info = json.loads(args.run_info)
        except ValueError:
            run_info = None
        if not isinstance(run_info, dict):
            raise RecorderUsageError(f"--run-info: not a JSON object: {args.run_info[:80]!r}")
    return RecorderOptions(run=args.run, out=Path(args.out), config_toml=toml_text, run_info=run_info,
                           compression=args.compression,
                           flush_interval_s=args.flush_ms / 1000.0, mirrors=not args.no_mirrors, fsync=args.fsync,
                           force=args.force, geo_origin=args.geo_origin, compact=not args.no_compact,
                           modes=cli_args.options_from(RecordModes, args)).validate()


def _origin_arg(text: str) -> tuple[float, float]:
    try:
        return parse_origin(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_record_args(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """The recorder's flags (shared by ``python -m recorder.process`` and ``truav-swarm record``)."""
    parser.add_argument("--run", required=True, help="run name: records every key under truav/<run>/")
    parser.add_argument("--out", "-o", required=True, metavar="FILE", help="MCAP file to write")
    parser.add_argument("--config-toml", metavar="FILE",
                        help="the run's config (as `truav config show` prints) to store as MCAP metadata")
    parser.add_argument("--run-info", metavar="JSON",
                        help="how the run was started beyond its config (a JSON object: seed, lockstep, ...), "
                             "stored as MCAP metadata for `truav log resim`")
    parser.add_argument("--compression", choices=sorted(COMPRESSIONS), default=DEFAULT_COMPRESSION,
                        help=f"chunk compression (default {DEFAULT_COMPRESSION})")
    parser.add_argument("--flush-ms", type=float, default=DEFAULT_FLUSH_INTERVAL_S * 1000, metavar="MS",
                        help="hand each chunk to the OS at most this old: a SIGKILL loses about this much "
                             f"(default {DEFAULT_FLUSH_INTERVAL_S * 1000:g})")
    parser.add_argument("--fsync", action="store_true", help="also fsync every chunk (survives power loss)")
    parser.add_argument("--no-mirrors", action="store_true",
                        help="skip the mirror channels for Foxglove (well-known schemas, JSON metrics)")
    parser.add_argument("--geo-origin", type=_origin_arg, default=DEFAULT_ORIGIN, metavar="LAT,LON",
                        help="where the area's centre sits on Foxglove's map, degrees (default %.4f,%.4f, Paris)"
                        % DEFAULT_ORIGIN)
    parser.add_argument("--no-compact", action="store_true",
                        help="keep the 50 ms chunks at a clean finish instead of rewriting them into chunks of "
                             "up to 2 s compressed harder")
    cli_args.add_options(parser.add_argument_group("split and snapshot (one file when none is given)"), RecordModes)
    parser.add_argument("--force", action="store_true", help="overwrite FILE if it exists")
    parser.add_argument("--summary-json", metavar="FILE", help="also write the summary as JSON here")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug lines: what was recorded, once a second")
    parser.add_argument("--router-wait", type=float, default=DEFAULT_ROUTER_WAIT_S, metavar="S",
                        help=f"client mode: wait this long for the router (default {DEFAULT_ROUTER_WAIT_S:g} s)")
    cli_args.add_transport_args(parser)
    return parser



def cmd_record(args: argparse.Namespace) -> int:
    """Record until SIGINT/SIGTERM/stop command; print the summary; exit code as in :mod:`recorder.process.recorder`."""
    from recorder.process.recorder import EXIT_USAGE, RecorderUsageError, record  # the node: mcap, zstd, foxglove

    try:
        options = options_from_args(args)
        transport.apply_creds(args, keys.SRC_RECORDER)
        zconfig = zenoh_config_from_args(args)
    except (RecorderUsageError, ValueError, OSError) as exc:
        print(f"recorder: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    if args.verbose:
        logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(name)s %(levelname)s %(message)s")
        logging.getLogger("truav").setLevel(logging.DEBUG)
    return record(options, zconfig, args.summary_json)


def main(argv: Optional[list[str]] = None) -> int:
    parser = cli_args.OneLineParser(
        prog="python -m recorder.process",
        description="Record every message of a TRUAV run (truav/<run>/**) into an MCAP file until "
                    "SIGINT/SIGTERM or a 'stop' command on truav/<run>/control/recorder; print a summary.")
    add_record_args(parser)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(name)s %(levelname)s %(message)s", stream=sys.stderr)
    return cmd_record(args)


if __name__ == "__main__":  # a swarm's recorder: ends, its file finished, without the interpreter's finalization
    from truav.lifecycle import exit_after_work
    exit_after_work(main())

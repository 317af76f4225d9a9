"""`truav-swarm schema`: the wire protocol on request, for authors of agents in other languages.

    truav-swarm schema --out schemas            # one JSON Schema per message kind + index.json (--force: again)
    truav-swarm schema --doc docs/reference/protocol.md   # regenerate the document's tables from the schema
    truav-swarm schema --doc docs/reference/protocol.md --check   # exit 1 if they are out of date

The JSON Schemas are the ones the recorder writes into every MCAP file (recorder.schemas.bus_schema),
one per kind of the schema's registry (truav.wire.messages.MESSAGE_CLASSES); docs/reference/protocol.md says
what every field means.
"""

from __future__ import annotations

import sys
from pathlib import Path

from truav import jsonio
from truav.checks import check_in_file, check_out_dir, make_dir
from truav.cli.config import UsageError
from truav.wire import protocol_doc
from truav.wire.messages import MESSAGE_CLASSES

INDEX_FILE = "index.json"


def schema_file(kind: str) -> str:
    """The file name of one kind's JSON Schema."""
    return f"{kind}.schema.json"


def output_names() -> list[str]:
    """The files `schema --out DIR` writes into DIR."""
    return [*(schema_file(kind) for kind in MESSAGE_CLASSES), INDEX_FILE]


def check_fresh(flag: str, out: Path, force: bool) -> None:
    """Without --force, DIR holds none of the files it would write (a second run, or another's index.json)."""
    there = [name for name in output_names() if (out / name).exists()]
    if there and not force:
        more = f" and {len(there) - 1} more of its files" if len(there) > 1 else ""
        raise UsageError(f"{flag} {out}: already holds {there[0]}{more}; choose another --out, or --force to "
                         f"overwrite them")


def write_schemas(out: Path) -> list[Path]:
    """Write one JSON Schema per kind and the index into ``out`` (which exists); the files written."""
    from recorder.schemas import SCHEMA_PREFIX, bus_schema
    written, index = [], {}
    for kind in MESSAGE_CLASSES:
        path = out / schema_file(kind)
        path.write_text(jsonio.dumps(bus_schema(kind), indent=1) + "\n")
        written.append(path)
        index[kind] = {"file": path.name, "title": SCHEMA_PREFIX + kind,
                       "key": f"truav/<run>/{protocol_doc.key_of(kind)}"}
    doc = {"description": "TRUAV bus messages: msgpack maps; one JSON Schema per kind (of the decoded map). "
                          "The meaning of every field: docs/reference/protocol.md", "kinds": index}
    (out / INDEX_FILE).write_text(jsonio.dumps(doc, indent=1) + "\n")
    return [*written, out / INDEX_FILE]


def cmd_schema(args) -> int:
    if args.out is None and args.doc is None:
        raise UsageError("give --out DIR (the JSON Schemas) or --doc FILE (docs/reference/protocol.md's tables)")
    if args.check and args.doc is None:
        raise UsageError("--check: checks --doc FILE; add --doc docs/reference/protocol.md")
    if args.force and args.out is None:
        raise UsageError("--force: overwrites the JSON Schemas of --out DIR; add --out DIR or drop it")
    if args.out is not None:
        out = check_out_dir("--out", args.out)
        check_fresh("--out", out, args.force)
        make_dir("--out", out)
        try:
            written = write_schemas(out)
        except OSError as exc:
            raise UsageError(f"--out {args.out}: cannot write ({exc.strerror or exc})") from None
        print(f"{len(written) - 1} JSON Schemas and {INDEX_FILE} in {out}")
    if args.doc is not None:
        path = check_in_file("--doc", args.doc)
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            raise UsageError(f"--doc {args.doc}: not UTF-8 text (give docs/reference/protocol.md)") from None
        try:
            new = protocol_doc.render_into(text)
        except ValueError as exc:
            raise UsageError(f"--doc {args.doc}: {exc}") from None
        if args.check:
            if new != text:
                stale = [name for name, part in protocol_doc.generated_parts(text).items()
                         if part != protocol_doc.sections()[name]]
                print(f"{args.doc}: generated tables out of date ({', '.join(stale)}); regenerate with "
                      f"`truav-swarm schema --doc {args.doc}`", file=sys.stderr)
                return 1
            print(f"{args.doc}: generated tables up to date")
        elif new != text:
            path.write_text(new)
            print(f"{args.doc}: generated tables rewritten")
        else:
            print(f"{args.doc}: generated tables already up to date")
    return 0


def add_schema_commands(sub) -> None:
    """The `schema` subcommand."""
    sc = sub.add_parser("schema", help="write the wire protocol's JSON Schemas, or regenerate docs/reference/protocol.md")
    sc.add_argument("--out", metavar="DIR", help="write one JSON Schema per message kind and index.json here")
    sc.add_argument("--doc", metavar="FILE", help="rewrite the generated tables of this document (docs/reference/protocol.md)")
    sc.add_argument("--check", action="store_true", help="with --doc: only check, exit 1 if out of date")
    sc.add_argument("--force", action="store_true", help="with --out: overwrite the files of an earlier run there")
    sc.set_defaults(func=cmd_schema)

"""docs/reference/protocol.md agrees with the schema: a kind, field, type, key, limit or refusal reason missing
or different fails here (regenerate the tables with `truav-swarm schema --doc docs/reference/protocol.md`).

The generated tables are compared with a fresh generation, and the document is also read back
(its tables parsed) and held against the schema registry directly, so a generator that forgot
something fails too. The JSON Schemas of `truav-swarm schema --out` (the recorder's) are held
against the same registry."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path
from typing import ClassVar

import pytest

from agents.process.agent_process import AgentOptions, DONE_ACK_ACTION
from agents.process.agent_process_realtime import REALTIME_BEACON_MAX_AGE_TICKS
from recorder.schemas import bus_schema
from truav.actions import HOVER, N_ACTIONS
from truav.bus import acl, placement
from truav.cli import swarm as swarm_cli
from truav.wire import guard, keys, protocol_doc, schema_names
from truav.wire.codec import unpack_limits
from truav.wire.field_checks import _uint63
from truav.wire.messages import Envelope, MESSAGE_CLASSES, size_limit
from world.process.world_process import WorldOptions

DOC_PATH = Path(__file__).resolve().parents[2] / "docs" / "reference" / "protocol.md"
DOC = DOC_PATH.read_text()
REGENERATE = "regenerate: truav-swarm schema --doc docs/reference/protocol.md"


def _rows(text: str) -> list[list[str]]:
    """The body rows of the markdown tables in ``text``, cells stripped, backticks dropped."""
    out = []
    for line in text.splitlines():
        if line.startswith("| ") and not line.startswith("| ---"):
            out.append([c.strip().strip("`") for c in re.split(r"(?<!\\)\|", line)[1:-1]])
    return out


def _part(name: str) -> str:
    part = protocol_doc.generated_parts(DOC)[name]
    assert part is not None, f"docs/reference/protocol.md lost its '{name}' markers"
    return part


def _kind_tables() -> dict[str, tuple[str, list[list[str]]]]:
    """kind -> (its documented key, its field rows) from the document's messages section."""
    out = {}
    for block in re.split(r"^#### ", _part("messages"), flags=re.M)[1:]:
        m = re.match(r"`([a-z_]+)` on `([^`]+)`", block)
        assert m, block[:80]
        out[m[1]] = (m[2], [r for r in _rows(block) if r[0] != "field"])
    return out


def test_generated_tables_are_up_to_date() -> None:
    fresh = protocol_doc.sections()
    for name, part in protocol_doc.generated_parts(DOC).items():
        assert part == fresh[name], f"docs/reference/protocol.md: the '{name}' table differs from the schema; {REGENERATE}"
    assert protocol_doc.render_into(DOC) == DOC, REGENERATE


def test_every_kind_and_field_is_documented_with_its_type_and_range() -> None:
    tables = _kind_tables()
    assert list(tables) == list(MESSAGE_CLASSES), "kinds missing from or extra in docs/reference/protocol.md"
    for kind, cls in MESSAGE_CLASSES.items():
        _, rows = tables[kind]
        assert [r[0] for r in rows] == list(cls.CHECKS), f"{kind}: fields differ"
        for (name, check), row in zip(cls.CHECKS.items(), rows):
            assert tuple(row[1:3]) == tuple(c.strip("`") for c in protocol_doc.describe(check)), (kind, name)
            assert row[4] and protocol_doc.NO_NOTE not in row[4], f"{kind}.{name}: no meaning given"
    assert protocol_doc.NO_NOTE not in DOC


def test_envelope_is_documented() -> None:
    rows = _rows(_part("envelope"))[1:]
    assert [r[0] for r in rows] == list(schema_names._ENVELOPE_KEYS)
    assert rows[0][2] == str(schema_names.SCHEMA_VERSION)
    assert all(k in rows[1][2] for k in MESSAGE_CLASSES)
    plan = {name: check for name, _, check in next(iter(MESSAGE_CLASSES.values()))._PLAN}
    for row in rows[2:]:
        assert tuple(row[1:3]) == tuple(c.strip("`") for c in protocol_doc.describe(plan[row[0]])), row


def _concrete(key: str) -> str:
    """A documented key with its placeholders filled in."""
    return "truav/r/" + key.replace("<i>", "2").replace("<scope>", "step").replace("<fault>", "loss") \
        .replace("<part>[/<part>...]", "shutdown").replace("<cx>_<cy>", "3_4").replace("<first>-<last>", "0-1").replace("<n>", "0")


def test_documented_keys_are_where_the_bus_expects_each_kind() -> None:
    for kind, (key, _) in _kind_tables().items():
        assert placement.expected_kind(_concrete(key)) == kind, (kind, key)
    keys_rows = {r[0]: r[1] for r in _rows(_part("keys"))[1:]}
    for kind in MESSAGE_CLASSES:
        assert keys_rows[protocol_doc.key_of(kind)] == kind
    assert placement.expected_kind(_concrete("uav/<i>/beacon/<cx>_<cy>")) == schema_names.KIND_BEACON
    for token in ("alive/world", "alive/uav/<i>", "alive/recorder", "alive/controller"):
        assert token in keys_rows
    assert keys.alive_uav("r", 2) == _concrete("alive/uav/<i>")


def test_limits_are_documented() -> None:
    rows = {r[0]: r[1:] for r in _rows(_part("limits"))[1:]}
    assert list(rows) == list(MESSAGE_CLASSES)
    for kind in MESSAGE_CLASSES:
        lim = unpack_limits(kind)
        assert rows[kind] == [str(size_limit(kind)), *(str(lim[k]) for k in (
            "max_map_len", "max_array_len", "max_str_len", "max_bin_len", "max_ext_len"))], kind
    consts = {r[0]: r[1] for r in _rows(_part("constants"))[1:]}
    assert consts["MAX_UAVS"] == str(keys.MAX_UAVS) and consts["TICK_WINDOW"] == str(guard.TICK_WINDOW)
    assert consts["BEACON_MAX_BYTES"] == str(schema_names.BEACON_MAX_BYTES)


def test_every_refusal_reason_is_documented() -> None:
    documented = [r[0] for r in _rows(_part("reasons"))[1:]]
    expected = {getattr(m, n) for m in (schema_names, guard, placement) for n in vars(m) if n.startswith("R_")}
    assert set(documented) == expected and len(documented) == len(expected)
    assert protocol_doc.KEY_MISMATCH == placement.R_KEY_MISMATCH


def test_action_numbering_is_the_worlds() -> None:
    from world.uavs import action_velocity
    import numpy as np
    rows = _rows(_part("actions"))[1:]
    assert [int(r[0]) for r in rows] == [*range(N_ACTIONS), HOVER]
    for r in rows:
        v = action_velocity(np.array(int(r[0])), 1.0)
        assert r[3] == f"({round(float(v[0]), 4) + 0.0:+.4f}, {round(float(v[1]), 4) + 0.0:+.4f})"
    assert "actions 0-7 fly at half of `speed_max`" in DOC and "8-15 at full speed" in DOC


def test_prose_facts_match_the_code() -> None:
    """What the hand-kept prose states from modules the generator may not import."""
    assert f"`deadline_frac` ({WorldOptions().deadline_frac:g})" in DOC
    assert f"the project's agents\nsend {DONE_ACK_ACTION}" in DOC
    assert f"freshest beacon of the last {REALTIME_BEACON_MAX_AGE_TICKS} ticks" in DOC
    assert f"{AgentOptions().beacon_phase:.0%} into it" in DOC
    assert f"`--wait-agents` seconds ({WorldOptions().wait_agents_s:g} by default)" in DOC


def test_the_agent_acl_is_documented() -> None:
    """Every key a UAV's identity may use under --secure is named in the document."""
    grant = next(g for g in acl.grants("r", 3) if g.identity == "uav/2")
    flat = " ".join(DOC.split())
    for expr in (*grant.put, *grant.subscribe, *grant.tokens, *grant.watch):
        documented = re.sub(r"/2(?=/|$)", "/<i>", expr.replace("truav/r/", "truav/<run>/"))
        assert f"`{documented}`" in flat, documented


def test_a_new_kind_in_the_registry_reaches_the_tables(monkeypatch) -> None:
    """The generator reads the registry, so a kind added there (e.g. another branch's) shows up, and
    the document is out of date until regenerated."""

    @dataclasses.dataclass(frozen=True)
    class Extra(Envelope):
        """Agent `uav` -> all: a test-only kind."""
        KIND: ClassVar[str] = "extra"
        PLACE: ClassVar[tuple[str, ...]] = (keys.UAV, "extra")
        CHECKS: ClassVar = {"uav": _uint63}
        uav: int

    monkeypatch.setattr(protocol_doc, "MESSAGE_CLASSES", {**MESSAGE_CLASSES, "extra": Extra})
    monkeypatch.setattr(protocol_doc, "size_limit", lambda kind: 1)
    fresh = protocol_doc.sections()
    assert "#### `extra` on `uav/<i>/extra`" in fresh["messages"] and protocol_doc.NO_NOTE in fresh["messages"]
    assert "| `extra` | 1 |" in fresh["limits"] and "`uav/<i>/extra`" in fresh["keys"]
    assert protocol_doc.render_into(DOC) != DOC


def test_describe_refuses_a_check_it_cannot_read() -> None:
    with pytest.raises(ValueError, match="cannot read the check"):
        protocol_doc.describe(lambda name, v: v)


def test_json_schemas_cover_every_kind_and_field(tmp_path, capsys) -> None:
    for kind, cls in MESSAGE_CLASSES.items():
        s = bus_schema(kind)
        assert set(s["properties"]) == {*schema_names._ENVELOPE_KEYS, *cls.CHECKS}, kind
        assert set(cls.CHECKS) - set(cls.SENT_IF_SET) <= set(s["required"]), kind
        assert not set(cls.SENT_IF_SET) & set(s["required"]), kind  # off the wire when empty: not required
    out = tmp_path / "schemas"
    assert swarm_cli.main(["schema", "--out", str(out)]) == 0
    index = json.loads((out / "index.json").read_text())
    assert list(index["kinds"]) == list(MESSAGE_CLASSES)
    for kind, entry in index["kinds"].items():
        assert json.loads((out / entry["file"]).read_text()) == bus_schema(kind)
        assert placement.expected_kind(_concrete(entry["key"].removeprefix("truav/<run>/"))) == kind


def test_schema_command_mistakes_are_one_line(tmp_path, capsys) -> None:
    (tmp_path / "file").write_text("x")
    for argv in (["schema", "--out", str(tmp_path / "file")], ["schema"], ["schema", "--check"],
                 ["schema", "--doc", str(tmp_path / "nowhere.md")], ["schema", "--doc", str(tmp_path / "file")]):
        assert swarm_cli.main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err, (argv, err)
    stale = tmp_path / "protocol.md"
    stale.write_text(DOC.replace("| `tick` | int |", "| `tick` | float |", 1))
    assert swarm_cli.main(["schema", "--doc", str(stale), "--check"]) == 1
    assert "out of date" in capsys.readouterr().err
    assert swarm_cli.main(["schema", "--doc", str(stale)]) == 0 and stale.read_text() == DOC
    assert swarm_cli.main(["schema", "--doc", str(stale), "--check"]) == 0


def test_schema_out_refuses_to_overwrite_without_force(tmp_path, capsys) -> None:
    """A second `schema --out DIR`, or a DIR holding someone's index.json: one line, exit 2, nothing
    written; --force overwrites. A --doc that is not UTF-8 text is one line too."""
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "index.json").write_text('{"mine": 1}')
    out = tmp_path / "schemas"
    assert swarm_cli.main(["schema", "--out", str(out)]) == 0
    capsys.readouterr()
    for argv in (["schema", "--out", str(out)], ["schema", "--out", str(theirs)], ["schema", "--force"]):
        assert swarm_cli.main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and ("--force" in err or "--out" in err), (argv, err)
    assert (theirs / "index.json").read_text() == '{"mine": 1}' and [p.name for p in theirs.iterdir()] == ["index.json"]
    assert swarm_cli.main(["schema", "--out", str(theirs), "--force"]) == 0
    assert "kinds" in json.loads((theirs / "index.json").read_text())
    (tmp_path / "bin.md").write_bytes(b"\xb2\xff\x00 not text")
    assert swarm_cli.main(["schema", "--doc", str(tmp_path / "bin.md")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not UTF-8 text" in err, err

"""Agents' health reports (uav/<i>/health): bounded, guarded, granted, shown by `status`, recorded."""

from __future__ import annotations

import io
import threading
import time

import msgpack
import pytest

from agents.process.agent_process import AgentNode, AgentOptions
from recorder.check import check
from recorder.mcap_log import McapLog
from recorder.reader import iter_messages, read_schemas
from tests.support.waits import wait_until
from truav.bus import security
from truav.cli import swarm as swarm_cli
from truav.config import Config
from truav.wire import guard, keys, schema

RUN = "health"


def _health(**kw) -> schema.Health:
    fields = {"uav": 1, "last_tick": 3, "steps": 3, "stale_obs_skipped": 0, "rejected": {}, "senders": {}} | kw
    return schema.Health(**fields)


def test_agent_rejections_show_in_status(bus_factory, endpoint, capsys) -> None:
    node = AgentNode(Config(), AgentOptions(run=RUN, uav=0), bus_factory("uav/0"))
    runner = threading.Thread(target=node.run, daemon=True)
    runner.start()
    try:
        attacker = bus_factory("world")  # may put anywhere in the run; the agent's guard judges the payloads
        for junk in (b"\xc1", b"", msgpack.packb([1, 2])):
            attacker.publish_raw(keys.uav_obs(RUN, 0), junk)
        forged = schema.Sequencer("mallory").stamp(schema.Control(command="shutdown", args={}))
        attacker.publish_raw(keys.control(RUN, "shutdown"), schema.encode(forged))
        assert wait_until(lambda: node.bus.rejections.total() == 4, 10)
        time.sleep(1.3)  # the next health report (once a second) carries them
        assert swarm_cli.main(["status", "--run", RUN, "-e", endpoint]) == 0
        out = capsys.readouterr().out
        line = next(x for x in out.splitlines() if "uav 0 rejected" in x)
        assert "uav 0 rejected 4 message(s)" in line and "forbidden_sender 1" in line and "not_msgpack" in line
        assert "mallory 1" in line and not node._stop.is_set()  # the forged shutdown was refused
    finally:
        node.stop()
        runner.join(10)


def test_health_reports_are_bounded_whatever_the_flood_sends(bus_factory) -> None:
    node = AgentNode(Config(), AgentOptions(run=RUN, uav=1), bus_factory("uav/1"))
    for n in range(1000):  # a flood of unique sender names, one with bytes no terminal should print
        node.bus.rejections.add(schema.R_NOT_MSGPACK, f"m{n}")
    node.bus.rejections.add(schema.R_BAD_TYPE, "evil\x1b[2J\u00e9")
    report = node.health()
    assert len(report.senders) <= schema.MAX_HEALTH_SENDERS and all(" " <= c <= "~" for s in report.senders for c in s)
    assert report.rejected == {schema.R_NOT_MSGPACK: 1000, schema.R_BAD_TYPE: 1}
    assert len(schema.encode(schema.Sequencer("uav/1").stamp(report))) < 1024
    with pytest.raises(schema.SchemaError):  # receivers refuse oversized maps
        _health(senders={f"s{n}": 1 for n in range(schema.MAX_HEALTH_SENDERS + 1)})
    with pytest.raises(schema.SchemaError):
        _health(rejected={f"r{n}": 1 for n in range(schema.MAX_HEALTH_REASONS + 1)})
    with pytest.raises(schema.SchemaError):
        _health(rejected={"not_msgpack": -1})


def test_only_agent_i_may_report_on_its_own_health_key(small_cfg) -> None:
    g = guard.for_config(small_cfg)
    own = schema.Sequencer("uav/1").stamp(_health())
    assert g.check(keys.uav_health(RUN, 1), own) is None
    forged = schema.Sequencer("mallory").stamp(_health())
    assert g.check(keys.uav_health(RUN, 1), forged)[0] == guard.R_SENDER
    table = security.grants(RUN, 3)
    lines = security.explain(table, key=keys.uav_health(RUN, 1))
    by_id = {line.split()[0]: line for line in lines[:-1]}
    assert "may put" in by_id["uav/1"] and "DENIED" in by_id["uav/2"]
    assert "may subscribe" in by_id["supervisor"] and "may subscribe" in by_id["recorder"]


def test_recorder_records_health_reports_and_log_check_accepts_them() -> None:
    buf = io.BytesIO()
    log = McapLog(buf, foxglove=False)
    k = keys.uav_health(RUN, 1)
    seq = schema.Sequencer("uav/1")
    for n in range(3):
        log.write(k, schema.encode(seq.stamp(_health(last_tick=n, rejected={"not_msgpack": n}))), 1_000 + n)
    log.close()
    got = list(iter_messages(io.BytesIO(buf.getvalue())))
    assert [m.key for m in got] == [k] * 3
    assert schema.decode(got[-1].payload, schema.KIND_HEALTH).rejected == {"not_msgpack": 2}
    assert read_schemas(io.BytesIO(buf.getvalue()))[k].name == "truav.health"  # its own schema, not "unknown"
    report = check(io.BytesIO(buf.getvalue()))
    assert report.problems == [] and report.messages == 3

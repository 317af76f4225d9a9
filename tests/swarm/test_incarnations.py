"""Issue 26: a restarted sender numbers its messages from 0 again under a new incarnation.

One small real-time swarm under the project's own deploy/plans/crash-and-freeze.toml (agent 1
SIGKILLed at 4 s and restarted 3 s later, agent 3 frozen for 2 s), recorded:

* `truav log check` passes the complete recording (before incarnations it counted the restarted
  agent's messages as duplicates);
* a copy with one message deleted from the restarted agent's stream fails it, naming the sender,
  its incarnation and the sequence number;
* so does the same recording with two runtime fault changes (one-shot `truav-swarm faults`
  commands, each a new `supervisor` incarnation numbering from 0);
* every agent's stats file says what each of its processes sent, equal to what was recorded.

Real time only bounds what it must: the run lasts 40 s of ticks at 10 Hz whatever the load, and the
test asserts nothing about deadlines (`max_missed_share` 1: a busy machine may miss actions).
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

from mcap.records import Channel, Message, Schema

from recorder.check import check
from recorder.mcap_log import McapLog
from recorder.reader import iter_messages, iter_salvaged_records, probe
from recorder.schemas import decode_envelope
from truav.config import Config
from truav.swarm.children import free_loopback_endpoint
from truav.swarm.supervisor import SwarmOptions, run_swarm

PLAN = Path(__file__).resolve().parents[2] / "deploy" / "plans" / "crash-and-freeze.toml"
RESTARTED = "uav/1"


def copy_without(src: Path, dst: Path, drop) -> int:
    """Copy a recording record by record, leaving out the messages ``drop(topic, payload)`` selects."""
    dropped = 0
    with open(src, "rb") as f, McapLog(dst, mirrors=False) as out:
        schemas: dict[int, int] = {}
        channels: dict[int, tuple[int, str]] = {}
        for record in iter_salvaged_records(f, probe(f)):
            if isinstance(record, Schema):
                schemas[record.id] = out.add_schema(record.name, record.encoding, record.data)
            elif isinstance(record, Channel):
                channels[record.id] = (out.add_channel(record.topic, record.message_encoding,
                                                       schemas.get(record.schema_id, 0), record.metadata),
                                       record.topic)
            elif isinstance(record, Message):
                cid, topic = channels[record.channel_id]
                if drop(topic, record.data):
                    dropped += 1
                    continue
                out.add_message(cid, record.sequence, record.log_time, record.publish_time, record.data)
    return dropped


def runtime_fault_changes(ep: str, world_log: Path, plans: list[Path], results: list) -> None:
    """Once the world ticks, two one-shot `truav-swarm faults` commands (each sends as `supervisor`,
    from seq 0, as its own process): a beacon loss, then an empty plan that clears it."""
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not (world_log.exists() and "starting" in world_log.read_text()):
        time.sleep(0.2)
    for plan in plans:
        results.append(subprocess.run([sys.executable, "-m", "truav.cli.swarm", "faults", "--run", "inc", "-e", ep,
                                       "--plan", str(plan)], capture_output=True, text=True, timeout=60).returncode)


def test_crash_and_freeze_recording_passes_log_check_and_a_deleted_message_is_named(tmp_path):
    cfg = Config().replace(scenario={"n_vehicles": 40, "steps_per_episode": 400, "n_uavs": 4},
                           roads={"warmup_steps": 5})
    out, mcap, ep = tmp_path / "swarm", tmp_path / "run.mcap", free_loopback_endpoint()
    loss, clear = tmp_path / "loss.toml", tmp_path / "clear.toml"
    loss.write_text('[[fault]]\nkind = "loss"\nprobability = 0.2\nkeys = "uav/*/beacon"\n')
    clear.write_text("")
    changes: list[int] = []
    changer = threading.Thread(target=runtime_fault_changes, args=(ep, out / "logs" / "world.log", [loss, clear],
                                                                   changes), daemon=True)
    changer.start()
    # 40 s of ticks: the restarted agent (back 3 s after its crash at 4 s) took 11 s to start on a loaded machine
    run_swarm(cfg, SwarmOptions(run="inc", episodes=1, out=str(out), plot=False, quiet=True, fault_plan=str(PLAN),
                                checkpoint_every=5, record=str(mcap), max_missed_share=1.0, listen=ep))
    changer.join(60)
    assert changes == [0, 0]
    assert "resumed from checkpoint" in (out / "logs" / "agent1.log").read_text()

    report = check(mcap)
    assert report.problems == [], report.format_report()
    one_shots = [s for k, s in report.senders.items() if k[:2] == ("supervisor", "control")]  # up's sends faults
    assert len(one_shots) == 2 and all(s.first_seq == 0 for s in one_shots), report.format_report()
    mine = [s for k, s in report.senders.items() if k[0] == RESTARTED]
    assert {s.incarnation for s in mine} == {1, 2}, report.format_report()
    # the restarted process's longest stream (its actions, or its health reports on a very slow machine)
    second = max((s for s in mine if s.incarnation == 2), key=lambda s: s.count)
    assert second.first_seq == 0 and second.count >= 3, report.format_report()

    # one message of the restarted process deleted: found, and named
    gone = second.last_seq // 2

    def the_one(topic: str, payload: bytes) -> bool:
        env = decode_envelope(payload)
        return env is not None and (env.src, env.kind, env.inc, env.seq) == (RESTARTED, second.kind, second.inc, gone)

    cut = tmp_path / "one-deleted.mcap"
    assert copy_without(mcap, cut, the_one) == 1
    damaged = check(cut)
    assert damaged.missing == 1 and len(damaged.problems) == 1, damaged.problems
    assert f"{RESTARTED} {second.kind}, incarnation 2 (inc {second.inc:016x}): seq {gone}" in damaged.problems[0]

    # what each agent process says it sent is what was recorded of its (uav, kind, incarnation) stream
    recorded = Counter()
    for message in iter_messages(mcap):
        env = decode_envelope(message.payload)
        if env is not None and env.src.startswith("uav/"):
            recorded[(env.src, env.kind, env.inc)] += 1
    for i in range(4):
        stats = json.loads((out / f"agent{i}.json").read_text())
        processes = stats["incarnations"]
        assert len(processes) == 1, processes  # agent 1's first process was SIGKILLed: it wrote nothing
        (me,) = processes
        assert me["inc"] == stats["incarnation"] and me["sent"] == stats["sent"]
        assert me["sent"]["health"] > 0 and (i == 1 or me["sent"]["action"] > 0)
        for kind, n in me["sent"].items():
            assert recorded[(f"uav/{i}", kind, int(me["inc"], 16))] == n, (i, kind, n)
    assert int(json.loads((out / "agent1.json").read_text())["incarnation"], 16) == second.inc


def test_a_restarted_agent_keeps_the_sent_counts_of_its_earlier_processes(tmp_path):
    """agent<i>.json lists every process of the run that wrote it: a restart (resumed from the
    checkpoint) keeps the earlier entries; a fresh start, another run's file or junk does not."""
    from types import SimpleNamespace

    from agents.process.agent_process import AgentNode

    path = tmp_path / "agent1.json"
    earlier = {"inc": "00000000000000a1", "steps_from": 0, "steps_to": 40,
               "sent": {"beacon": 40, "action": 40, "state": 0, "health": 5}}
    path.write_text(json.dumps({"run": "r", "incarnations": [earlier]}))

    def kept(resumed: bool, run: str = "r") -> list:
        node = SimpleNamespace(resumed=resumed, opts=SimpleNamespace(stats_out=str(path), run=run))
        return AgentNode._read_earlier_incarnations(node)

    assert kept(True) == [earlier]
    assert kept(False) == [] and kept(True, run="other") == []
    path.write_text("{not json")
    assert kept(True) == []

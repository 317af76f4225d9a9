"""Seekable replay on a loopback router: seek, rate and step-by-tick through the Zenoh queryable
(``truav/<run>/replay/ctl``), through ``truav-swarm replay-ctl`` and through control messages; a fresh
subscriber after a seek gets the last message of every channel; the status message while playing;
``--lockstep`` with a live agent process and with an agent that never answers; the ACL grants.

Engine-level behaviour (positions, restores, keys, parts) is tests/unit/test_replay_seek.py."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import msgpack
import pytest

from recorder.mcap_log import McapLog
from recorder.process.replay_bus import ask_replay, replay_on_bus
from recorder.replay import ReplayOptions
from truav.bus import acl, transport
from truav.bus.transport import Bus, QueryRefused
from truav.cli.config import UsageError
from truav.cli.swarm import build_parser
from truav.wire import keys, schema
from tests.support.ticks import PER_TICK, landed_on, last_before, make_ticks, of_tick
from tests.support.waits import wait_until as _wait_until

RUN = "ctl"
WAIT_S = 15.0
T0 = 1_700_000_000_000_000_000
MS = 1_000_000


def wait_until(pred, timeout: float = WAIT_S) -> bool:
    return _wait_until(pred, timeout, 0.01)


class Sink:
    def __init__(self) -> None:
        self.items: list[tuple[str, bytes]] = []
        self.lock = threading.Lock()

    def __call__(self, key: str, raw: bytes, *_: object) -> None:
        if "/replay/" not in key and "/control/" not in key:
            with self.lock:
                self.items.append((key, raw))

    def count(self) -> int:
        with self.lock:
            return len(self.items)

    def since(self, n: int) -> list[tuple[str, bytes]]:
        with self.lock:
            return self.items[n:]


def ready(bus: Bus, sink: Sink, run: str = RUN) -> None:
    """Subscribe ``sink`` to the run and make sure the router knows (a probe put comes back)."""
    bus.subscribe_raw(keys.everything(run), sink)
    probes: list[str] = []
    bus.subscribe_raw(keys.control(run, "probe"), lambda k, raw, t: probes.append(k))
    deadline = time.monotonic() + WAIT_S
    while not probes and time.monotonic() < deadline:
        bus.publish_raw(keys.control(run, "probe"), b"probe")
        wait_until(lambda: bool(probes), 0.05)
    assert probes, "subscription never became ready"


class Running:
    """``replay_on_bus`` in a thread, its console lines kept; ``ask`` retries until its queryable is up."""

    def __init__(self, endpoint: str, options: ReplayOptions) -> None:
        self.lines: list[str] = []
        self.stats = None
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, args=(endpoint, options), daemon=True)
        self.thread.start()

    def _run(self, endpoint: str, options: ReplayOptions) -> None:
        self.stats = replay_on_bus(options, transport.make_config("client", connect=[endpoint]), stop=self.stop,
                                   on_state=self.lines.append)

    def wait_serving(self, bus: Bus, run: str = RUN) -> schema.ReplayStatus:
        deadline = time.monotonic() + WAIT_S
        while True:
            try:
                return ask_replay(bus, run, "status", {}, timeout=1.0)
            except QueryRefused:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.05)

    def end(self) -> None:
        self.stop.set()
        self.thread.join(WAIT_S)
        assert not self.thread.is_alive()


@pytest.fixture
def paused_replay(tmp_path: Path, endpoint: str):
    written = make_ticks(tmp_path / "r.mcap", ticks=60, gap_ms=10.0, run=RUN)
    running = Running(endpoint, ReplayOptions(path=tmp_path / "r.mcap", paused=True))
    yield written, running
    running.end()


def test_seek_over_the_queryable_gives_a_fresh_subscriber_every_channel(paused_replay, bus_factory) -> None:
    written, running = paused_replay
    operator = bus_factory("supervisor")
    first = running.wait_serving(operator)
    assert first.state == schema.REPLAY_PAUSED and first.sent == 0 and first.tick == -1
    late = Sink()
    ready(bus_factory("late"), late)  # joins now: it has seen nothing of the replay
    status = ask_replay(operator, RUN, "seek", {"tick": 40})
    assert status.tick == 40 and status.paused and status.restored == PER_TICK
    assert wait_until(lambda: late.count() == PER_TICK)
    assert late.since(0) == landed_on(written, 40)  # every channel's last message before tick 40, then tick 40
    status = ask_replay(operator, RUN, "step", {})
    assert wait_until(lambda: late.count() == 2 * PER_TICK - 1)
    assert late.since(PER_TICK) == of_tick(written, 40)[1:]
    status = ask_replay(operator, RUN, "seek", {"s": 0.1})  # back in time: tick 10 starts at 0.1 s
    assert wait_until(lambda: late.count() == 3 * PER_TICK - 1)
    assert late.since(2 * PER_TICK - 1) == last_before(written, 10) and status.tick == 9
    assert ask_replay(operator, RUN, "rate", {"rate": 3}).rate == 3.0
    with pytest.raises(QueryRefused, match="tick 999 is not in the replayed window"):
        ask_replay(operator, RUN, "seek", {"tick": 999})
    with pytest.raises(QueryRefused, match="unknown replay command"):
        ask_replay(operator, RUN, "rewind", {})


def test_replay_ctl_command_line(paused_replay, bus_factory, endpoint: str, capsys) -> None:
    written, running = paused_replay
    running.wait_serving(bus_factory("supervisor"))
    late = Sink()
    ready(bus_factory("late"), late)

    def ctl(*argv: str) -> int:
        args = build_parser().parse_args(["replay-ctl", "--run", RUN, "-e", endpoint, *argv])
        return args.func(args)

    assert ctl("seek", "--tick", "40") == 0
    assert "paused at 0.400/0.590 s tick 40, rate 1" in capsys.readouterr().out
    assert wait_until(lambda: late.count() == PER_TICK) and late.since(0) == landed_on(written, 40)
    assert ctl("rate", "2") == 0 and "rate 2," in capsys.readouterr().out
    assert ctl("step") == 0  # the rest of tick 40
    assert wait_until(lambda: late.count() == 2 * PER_TICK - 1) and late.since(PER_TICK) == of_tick(written, 40)[1:]
    assert ctl("burst", "2") == 0
    assert wait_until(lambda: late.count() == 4 * PER_TICK - 1)
    assert late.since(2 * PER_TICK - 1) == of_tick(written, 41) + of_tick(written, 42)
    capsys.readouterr()
    assert ctl("seek", "--tick", "999") == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "tick 999 is not in the replayed window" in err[0]
    assert ctl("status") == 0 and "tick 42" in capsys.readouterr().out
    args = build_parser().parse_args(["replay-ctl", "--run", "nobody", "--timeout", "0.5", "-e", endpoint, "status"])
    assert args.func(args) == 1 and "no answer" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:
        build_parser().parse_args(["replay-ctl", "--run", RUN, "rate", "0"])
    assert exit_info.value.code == 2


def test_control_messages_set_rate_and_step_a_tick_and_status_is_published(paused_replay, bus_factory) -> None:
    written, running = paused_replay
    operator = bus_factory("supervisor")
    running.wait_serving(operator)
    statuses: list[schema.ReplayStatus] = []
    operator.subscribe(keys.replay_status(RUN), lambda k, msg, raw, t: statuses.append(msg))  # schema-checked
    late = Sink()
    ready(bus_factory("late"), late)
    command_key = keys.control(RUN, "replay")
    operator.publish(command_key, schema.Control(command="rate", args={"rate": 4}))
    assert wait_until(lambda: any(s.rate == 4.0 for s in statuses))
    operator.publish(command_key, schema.Control(command="step", args={}))
    assert wait_until(lambda: late.count() == PER_TICK)
    assert late.since(0) == of_tick(written, 0)
    time.sleep(0.3)
    assert late.count() == PER_TICK  # one tick, then paused
    operator.publish(command_key, schema.Control(command="resume", args={}))
    assert wait_until(lambda: late.count() == len(written))
    assert late.since(0) == [(k, p) for k, p, _ in written]
    assert wait_until(lambda: any(s.state == schema.REPLAY_ENDED for s in statuses))
    assert all(isinstance(s, schema.ReplayStatus) and s.src == keys.SRC_REPLAY for s in statuses)
    assert sum(s.state == schema.REPLAY_PAUSED for s in statuses) >= 2  # about 5 Hz while it waited


def world_ticks(path: Path, run: str, uav: int, ticks: int, gap_ms: float, n_uavs: int = 5) -> None:
    """What the world sent to agent ``uav`` (ticks and its observations), ``gap_ms`` apart, and a recorded
    action of that agent (which a lock-step replay leaves out: the live agent answers)."""
    world, agent = schema.Sequencer("world"), schema.Sequencer(keys.uav_identity(uav))
    with McapLog(path) as log:
        for tick in range(ticks):
            t = T0 + round(tick * gap_ms * MS)
            log.write(keys.world_tick(run), schema.encode(world.stamp(schema.Tick(
                tick=tick, episode=0, sim_time=float(tick), deadline_ms=80.0, n_uavs=n_uavs))), t)
            log.write(keys.uav_obs(run, uav), schema.encode(world.stamp(schema.Obs(
                tick=tick, episode=0, uav=uav, pos=(1000.0 + 10 * tick, 2000.0), vehicles_in_range=4,
                queued_packets=2, relayed=1, covered=4, energy_j=100.0, speed_max=15.0, done=False))), t + MS)
            log.write(keys.uav_action(run, uav), schema.encode(agent.stamp(schema.Action(
                uav=uav, tick=tick, action=7))), t + 2 * MS)


def test_lockstep_replay_paces_the_recorded_world_by_a_live_agent(tmp_path: Path, endpoint: str, bus_factory) -> None:
    """Each recorded tick goes out once the live agent answered the last one, as fast as it answers.

    The agent takes 100 ms per observation (DELAY_ENV) and, in real time, answers only the newest of
    several waiting observations: it answers every tick once, in order, only if each observation waited
    for its answer to the last. Ticks recorded 2 s apart go out at the agent's pace, not the recording's."""
    from agents.process.agent_process import DELAY_ENV

    uav, ticks, run, gap_ms = 1, 8, "lockstep", 2000.0
    world_ticks(tmp_path / "world.mcap", run, uav, ticks, gap_ms)
    answers: list[int] = []
    lock = threading.Lock()

    def note(key: str, raw: bytes, _t: int) -> None:
        with lock:
            answers.append(msgpack.unpackb(raw)["tick"])

    watcher = bus_factory("watcher", run)
    watcher.subscribe_raw(keys.uav_action(run, uav), note)
    repo = Path(__file__).resolve().parents[2]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(repo), os.environ.get("PYTHONPATH", "")]),
           DELAY_ENV: f"{uav}:100"}
    agent = subprocess.Popen([sys.executable, "-m", "truav.cli.swarm", "agent", "--id", str(uav), "--run", run,
                              "--greedy", "--accept-replay", "-e", endpoint], env=env, stdin=subprocess.DEVNULL,
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    lines: list[str] = []
    try:
        assert wait_until(lambda: bool(watcher.alive(keys.alive_uav(run, uav), timeout=0.5)), 60.0), \
            "agent never came up"
        began = time.monotonic()
        stats = replay_on_bus(ReplayOptions(path=tmp_path / "world.mcap", lockstep=True, lockstep_wait_s=60.0),
                              transport.make_config("client", connect=[endpoint]), on_state=lines.append)
        took = time.monotonic() - began
        assert wait_until(lambda: len(answers) >= ticks)
    finally:
        agent.kill()  # by PID
        agent.wait(WAIT_S)
        assert agent.stderr is not None
        agent.stderr.close()
    assert stats.published == 2 * ticks and not any("did not answer" in line for line in lines), lines
    assert stats.lockstep_held == ticks - 1 and stats.lockstep_given_up == 0
    with lock:
        assert answers == list(range(ticks))  # the live agent's answers, each tick once: the recorded ones stayed out
    assert took < (ticks - 1) * gap_ms / 1000 / 2, took  # paced by the agent, not by the recording


def test_lockstep_goes_on_without_an_agent_that_never_answers(tmp_path: Path, bus_factory, endpoint: str,
                                                                capsys) -> None:
    """A live agent (its token present) that never answers is waited for --lockstep-wait once, named, then
    no longer waited for; the replay ends, and its summary and exit code 1 say that it was not paced throughout."""
    run = "mute"
    world_ticks(tmp_path / "world.mcap", run, 0, 4, 10.0)
    mute = bus_factory(keys.uav_identity(0), run)
    mute.declare_liveliness(keys.alive_uav(run, 0))  # alive, listening to nothing, answering nothing
    watcher = bus_factory("watcher", run)
    assert wait_until(lambda: bool(watcher.alive(keys.alive_uav(run, 0), timeout=0.5)))
    args = build_parser().parse_args(["replay", str(tmp_path / "world.mcap"), "--lockstep", "--lockstep-wait", "0.5",
                                      "--no-keys", "-e", endpoint])
    assert args.func(args) == 1
    out, err = capsys.readouterr()
    refusals = [line for line in err.splitlines() if "did not answer" in line]
    assert refusals == ["replay: lockstep: uav 0 did not answer tick 0 within 0.5 s (--lockstep-wait); going on "
                        "without it (not waited for until it answers again)"]  # once: then it is not waited for
    assert "replay: 8 messages" in out and "lock-step: 3 tick(s) held for the live agents' answers, 1 answer(s) " \
                                           "not received in time" in out
    assert err.strip().splitlines()[-1] == ("truav-swarm: error: --lockstep: 1 answer(s) of live agents not received "
                                            "within --lockstep-wait 0.5 s")


def test_acl_lets_the_replay_serve_and_the_operator_ask_only() -> None:
    table = acl.grants("demo", 2)
    ctl = keys.replay_ctl(acl.replay_run("demo"))
    by_identity = {line.split()[0]: line for line in acl.explain(table, key=ctl) if ":" in line}
    assert "may serve queries" in by_identity["replay"]
    assert "may query" in by_identity["supervisor"]
    for identity in ("world", "uav/0", "recorder", "view", "controller"):
        assert "DENIED" in by_identity[identity], by_identity[identity]
    config = acl.acl_config(table)
    rules = {r["id"]: r for r in config["rules"]}
    assert rules["replay-serve"]["key_exprs"] == [ctl] and "declare_queryable" in rules["replay-serve"]["messages"]
    assert rules["supervisor-ask"]["key_exprs"] == [ctl] and rules["supervisor-ask"]["messages"] == ["query"]
    assert keys.replay_status(acl.replay_run("demo")) in next(g for g in table if g.identity == "supervisor").subscribe


def test_under_secure_only_the_operator_may_steer_the_replay(tmp_path: Path, capsys) -> None:
    """On a locked router (mutual TLS, the ACL of truav.bus.acl): `replay --creds` publishes into the run's
    replay run and serves its replay/ctl there; `replay-ctl --creds` (the operator, supervisor) gets answers;
    an agent's or the world's query reaches nothing."""
    import zenoh

    from tests.support.waits import free_port
    from truav.bus import security

    run = "sec"
    creds_dir = tmp_path / "creds"
    security.issue(creds_dir, run, 2, f"tcp/127.0.0.1:{free_port()}")
    creds = security.load(creds_dir, run)
    router = zenoh.open(zenoh.Config.from_file(str(creds_dir / security.ROUTER_CONFIG)))
    replay_run = acl.replay_run(run)
    make_ticks(tmp_path / "r.mcap", ticks=20, gap_ms=10.0, run=run)
    exits: list[int] = []
    replay_args = build_parser().parse_args(["replay", str(tmp_path / "r.mcap"), "--paused", "--no-keys", "--quiet",
                                             "--creds", str(creds_dir)])
    worker = threading.Thread(target=lambda: exits.append(replay_args.func(replay_args)), daemon=True)
    worker.start()

    def ctl(*argv: str) -> int:
        args = build_parser().parse_args(["replay-ctl", "--creds", str(creds_dir), "--timeout", "1", *argv])
        return args.func(args)

    buses = {i: Bus(i, run, zenoh.Config.from_file(str(creds.config_file(i)))) for i in ("uav/0", "world")}
    try:
        deadline = time.monotonic() + WAIT_S
        while ctl("seek", "--tick", "5") != 0:
            assert time.monotonic() < deadline, capsys.readouterr()
        assert "paused at 0.050/0.190 s tick 5" in capsys.readouterr().out
        for identity in ("uav/0", "world"):
            with pytest.raises(QueryRefused, match="no answer"):
                ask_replay(buses[identity], replay_run, "resume", {}, timeout=1.0)
        assert ctl("status") == 0 and "paused at" in capsys.readouterr().out  # nobody else resumed it
        with pytest.raises(UsageError, match="a replay publishes into 'sec-replay'"):
            ctl("--run", "other", "status")
    finally:
        ctl("quit")
        worker.join(WAIT_S)
        for bus in buses.values():
            bus.close()
        router.close()
    assert not worker.is_alive() and exits == [0]


def test_replay_lockstep_wait_defaults_to_the_worlds() -> None:
    args = build_parser().parse_args(["replay", "x.mcap", "--lockstep"])
    assert args.lockstep and args.lockstep_wait == schema.DEFAULT_LOCKSTEP_WAIT_S == ReplayOptions("x").lockstep_wait_s


def test_a_queryable_bounds_what_it_takes_and_survives_its_handler(bus_factory) -> None:
    """Bus.serve: a query over its size limit is refused unread, a failing handler is an error answer
    (the server goes on), and an answer over the asker's limit is refused by the asker."""
    server, client = bus_factory("replay", "q"), bus_factory("supervisor", "q")
    key = keys.replay_ctl("q")

    def handler(data: bytes) -> tuple[bool, bytes]:
        if data == b"boom":
            raise RuntimeError("handler bug")
        return True, data * 2

    server.serve(key, handler, max_bytes=8)
    deadline = time.monotonic() + WAIT_S
    while True:
        try:
            assert client.ask(key, b"ab", timeout=1.0) == b"abab"
            break
        except QueryRefused:
            assert time.monotonic() < deadline
    with pytest.raises(QueryRefused, match="query of 9 bytes, limit 8"):
        client.ask(key, b"x" * 9)
    with pytest.raises(QueryRefused, match="internal error: RuntimeError: handler bug"):
        client.ask(key, b"boom")
    with pytest.raises(QueryRefused, match="answer of 8 bytes, limit 4"):
        client.ask(key, b"abcd", max_bytes=4)
    assert client.ask(key, b"ok") == b"okok"

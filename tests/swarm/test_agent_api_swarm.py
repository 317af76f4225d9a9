"""The agent API on the bus: `truav-swarm up --lockstep --agent NAME` (one agent process per UAV, each
running agents.api_decision) flies exactly what the in-process adapter (agents.api_controller) flies:
episode for episode the same metrics, the same actions at every step (the world's digest of them)
and the same end positions; a class that fails mid-run makes its UAV hover, counted, and the run goes on.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np

from tests.support.runs import run_to_end
from agents.api_controller import ApiController
from agents.random_agent import RandomAgent
from truav.analysis.driver import run_episodes
from truav.config import to_toml
from tests.support.lockstep import Recorder

from tests.support.tutorial_agent import USER_MODULE
from tests.support.agent_api_swarm import CFG, EPISODES, METRICS, SEED, SWARM_TIMEOUT_S, up


def test_lockstep_swarm_of_the_random_agent_equals_training_it(tmp_path):
    rec = Recorder(ApiController("random", RandomAgent, CFG, [SEED]))
    expected = run_episodes(CFG, [SEED], rec, EPISODES)
    out = up(tmp_path, "apirandom", "--agent", "random")
    world = json.loads((out / "world.json").read_text())
    assert world["deadline_misses"] == 0 and world["hover_answers"] == 0
    assert len(rec.digests) == EPISODES and world["actions_digest"] == rec.digests  # every action of every step
    assert np.array_equal(np.array(world["end_positions"]), np.array(rec.end_pos))
    for e, got in enumerate(world["episodes"]):
        for k in METRICS:
            assert np.array_equal(got[k], expected[k][e, 0], equal_nan=True), (e, k)


GOSSIP = textwrap.dedent('''
    from agents.api import UavAgent

    class Gossip(UavAgent):
        """Flies by what its peers' beacons say: a field each peer drew after its last act."""
        def act(self, view):
            heard = sum(b.fields.get("draw", 0) for b in view.beacons)
            flags = sum(bool(b.fields.get("even")) for b in view.beacons)
            self.draw = int(self.rng.integers(1000))
            return (heard + flags + self.draw) % 16
        def beacon_fields(self):
            return {"draw": self.draw, "even": self.draw % 2 == 0, "share": self.draw / 1000.0}
''')


def test_beacon_fields_go_out_on_the_bus_and_the_swarm_flies_what_training_flies(tmp_path):
    """A class steering by its peers' beacon fields: a lock-step swarm of it (its fields in each UAV's beacon,
    over Zenoh) takes the in-process adapter's action at every step; its recording holds the fields."""
    (tmp_path / "gossip.py").write_text(GOSSIP)
    sys.path.insert(0, str(tmp_path))
    try:
        from gossip import Gossip
        rec = Recorder(ApiController("gossip", Gossip, CFG, [SEED]))
        run_episodes(CFG, [SEED], rec, EPISODES)
    finally:
        sys.path.remove(str(tmp_path))
        sys.modules.pop("gossip", None)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")])}
    record = tmp_path / "gossip.mcap"
    out = up(tmp_path, "gossip", "--agent", "gossip:Gossip", "--record", str(record), env=env)
    world = json.loads((out / "world.json").read_text())
    assert world["hover_answers"] == 0 and world["actions_digest"] == rec.digests  # every action of every step
    from recorder.reader import iter_messages
    from truav.wire import schema
    beacons = [schema.decode(payload) for _, payload, _, _ in iter_messages(record, include=["*/uav/*/beacon"])]
    with_fields = [b for b in beacons if b.fields]
    assert with_fields and set(with_fields[0].fields) == {"draw", "even", "share"}
    # an episode's first beacon carries none (no act yet), every later one does (T + 1 ticks an episode: its `done` one)
    assert all(bool(b.fields) == (b.tick % (CFG.scenario.steps_per_episode + 1) != 0) for b in beacons), \
        [(b.tick, b.fields) for b in beacons][:20]


def test_a_user_class_failing_on_the_bus_hovers_its_uav_and_the_run_goes_on(tmp_path):
    (tmp_path / "flaky.py").write_text(textwrap.dedent('''
        from agents.api import UavAgent

        class Flaky(UavAgent):
            call_limit_s = 0.3
            def act(self, view):
                self.step = view.step
                if self.uav == 1 and view.step == 3:
                    raise RuntimeError("lost the plot")
                while self.uav == 3 and view.step == 6:
                    pass  # hangs: the call limit ends it
                return 8 if self.uav == 2 and view.step == 5 else 0
            def beacon_fields(self):  # no beacon carries a str: UAV 0's action is missed from step 1 on
                return {"note": "text"} if self.uav == 0 and self.step > 0 else {}
    '''))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")])}
    rec = tmp_path / "flaky.mcap"
    out = up(tmp_path, "flaky", "--agent", "flaky:Flaky", "--record", str(rec), "--tolerate-agent-errors",
             env=env)  # the run goes on; without the flag it fails (tests/swarm/test_honest_verdicts.py)
    agents = [json.loads((out / f"agent{i}.json").read_text()) for i in range(CFG.scenario.n_uavs)]
    T = CFG.scenario.steps_per_episode
    assert [a["agent_errors"] for a in agents] == [EPISODES * (T - 1), EPISODES, 0, EPISODES]
    assert agents[0]["first_agent_error"] == "beacon_fields['note'] must be a bool, int or float, got str"
    assert agents[1]["first_agent_error"] == "act raised RuntimeError: lost the plot"
    assert agents[3]["first_agent_error"] == "act took longer than 0.3 s (its call_limit_s)"
    assert "agent flaky:Flaky: act raised RuntimeError: lost the plot" in (out / "logs" / "agent1.log").read_text()
    world = json.loads((out / "world.json").read_text())
    assert len(world["episodes"]) == EPISODES
    # Its recording re-simulates, the class's failures (a hovered tick each) included, once --agent names it.
    resim = [sys.executable, "-m", "truav.cli", "log", "resim", str(rec), "--quiet"]
    refused = subprocess.run(resim, env=env, capture_output=True, text=True, timeout=120)
    assert refused.returncode == 2 and "give --agent flaky:Flaky" in refused.stderr \
        and len(refused.stderr.strip().splitlines()) == 1, refused.stderr
    other = subprocess.run([*resim, "--agent", "random"], env=env, capture_output=True, text=True, timeout=120)
    assert other.returncode == 2 and "was flown by 'flaky:Flaky'" in other.stderr, other.stderr
    ok = subprocess.run([*resim, "--agent", "flaky:Flaky"], env=env, capture_output=True, text=True, timeout=300)
    assert ok.returncode == 0 and "result: reproduced" in ok.stdout, ok.stdout + ok.stderr
    assert f"the class failed {2 * EPISODES + EPISODES * (T - 1)} call(s)" in ok.stdout, ok.stdout


def test_a_learning_class_from_outside_the_repo_flies_to_the_state_training_reaches(tmp_path):
    """The tutorial's Bandit (tests/swarm/test_agent_api.py), trained in process and flown as a lock-step swarm:
    every agent process ends with the state_dict training ends with, array for array."""
    from truav.analysis.trainer import run_chunk
    mods = tmp_path / "mylab"
    mods.mkdir()
    (mods / "bandit_agent.py").write_text(USER_MODULE)
    sys.path.insert(0, str(mods))
    try:
        trained = run_chunk("agent:bandit_agent:Bandit", CFG, [SEED], EPISODES)
    finally:
        sys.path.remove(str(mods))
        sys.modules.pop("bandit_agent", None)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(mods), os.environ.get("PYTHONPATH", "")])}
    out = up(tmp_path, "bandit", "--agent", "bandit_agent:Bandit", env=env)
    world = json.loads((out / "world.json").read_text())
    for e, got in enumerate(world["episodes"]):
        for k in METRICS:
            assert np.array_equal(got[k], trained.metrics[k][e, 0], equal_nan=True), (e, k)
    assert trained.policy["count"].sum() == EPISODES * CFG.scenario.steps_per_episode * CFG.scenario.n_uavs
    for uav in range(CFG.scenario.n_uavs):
        with np.load(out / f"agent{uav}.npz") as ck:
            for k in ("value", "count"):
                assert np.array_equal(ck[f"state.{k}"], trained.policy[k][0, uav]), (uav, k)


def test_a_lockstep_swarm_of_truav_through_the_api_ends_with_truav_trains_q_tables(tmp_path):
    """`truav-swarm up --lockstep --agent truav` (TRUAV's learner as an API class, one process per UAV) ends
    with the Q-tables of the trainer's own TRUAV, entry for entry."""
    from truav.analysis.trainer import run_chunk
    trained = run_chunk("truav", CFG, [SEED], EPISODES)
    out = up(tmp_path, "apitruav", "--agent", "truav")
    world = json.loads((out / "world.json").read_text())
    for e, got in enumerate(world["episodes"]):
        for k in METRICS:
            assert np.array_equal(got[k], trained.metrics[k][e, 0], equal_nan=True), (e, k)
    for uav in range(CFG.scenario.n_uavs):
        with np.load(out / f"agent{uav}.npz") as ck:
            assert np.array_equal(ck["state.q"], trained.q[0, uav]), uav


def test_a_crashed_agent_of_a_user_class_resumes_its_state_from_its_checkpoint(tmp_path):
    """Real time, 10 Hz: UAV 1's process is SIGKILLed at 6 s and restarted 2 s later; it resumes from its
    checkpoint (taken every 50 steps), so its state counts every step it learned, before and after."""
    mods = tmp_path / "mylab"
    mods.mkdir()
    (mods / "bandit_agent.py").write_text(USER_MODULE)
    plan = tmp_path / "crash.toml"
    plan.write_text('[[fault]]\nkind = "crash"\nstart = 6.0\nuav = 1\nrestart_after = 2.0\n')
    scenario = tmp_path / "rt.toml"
    scenario.write_text(to_toml(CFG.replace(scenario={"steps_per_episode": 120})))
    out = tmp_path / "rt"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(mods), os.environ.get("PYTHONPATH", "")])}
    cmd = [sys.executable, "-m", "truav.cli.swarm", "up", "--seed", str(SEED), "--run", "rt", "--episodes", "1",
           "--scenario", str(scenario), "--out", str(out), "--quiet", "--no-plot", "--agent", "bandit_agent:Bandit",
           "--fault-plan", str(plan),
           "--max-missed", "1"]  # the crash's missed actions (real time) are not what this test is about
    assert run_to_end(cmd, tmp_path / "rt.log", SWARM_TIMEOUT_S, env=env) == 0, (tmp_path / "rt.log").read_text()
    stats = json.loads((out / "agent1.json").read_text())
    resumed_at = stats["incarnations"][-1]["steps_from"]
    assert resumed_at > 0  # the restarted process started from the checkpoint's step count
    with np.load(out / "agent1.npz") as ck:
        assert int(ck["state.count"].sum()) == int(ck["steps"]) > resumed_at  # the state learned before the crash too


def _train(tmp: Path, name: str, *extra: str) -> Path:
    scenario = tmp / "train.toml"
    scenario.write_text(to_toml(CFG))
    out = tmp / name
    cmd = [sys.executable, "-m", "truav.cli", "train", "--config", str(scenario), "--seeds", "1", "--seed-start",
           str(SEED), "--episodes", "3", "--out", str(out), "--quiet", *extra]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=SWARM_TIMEOUT_S)
    assert done.returncode == 0, done.stderr
    return out


def test_a_swarm_of_a_class_starts_from_what_truav_train_agent_learned(tmp_path):
    """`up --agent truav --qtable RUN` (RUN from `truav train --agent truav`) loads each UAV's trained state
    (its Q-table, exploration generator and epsilon: where training stopped) and learns on: it flies, and
    ends with, what the in-process adapter started from the same state flies, entry for entry; its
    recording re-simulates bit for bit from the same start."""
    from agents.truav_agent import TruavAgent
    from truav.analysis.agent_run import read_agent_state
    agent_run = _train(tmp_path, "trained-api", "--agent", "truav")
    _, _, state, _ = read_agent_state(agent_run)
    rec = Recorder(ApiController("truav", TruavAgent, CFG, [SEED], state=state))
    expected = run_episodes(CFG, [SEED], rec, EPISODES)
    recording = tmp_path / "api.mcap"
    out = up(tmp_path, "apistart", "--agent", "truav", "--qtable", str(agent_run), "--record", str(recording))
    world = json.loads((out / "world.json").read_text())
    assert world["actions_digest"] == rec.digests
    for e, got in enumerate(world["episodes"]):
        for k in METRICS:
            assert np.array_equal(got[k], expected[k][e, 0], equal_nan=True), (e, k)
    for uav in range(CFG.scenario.n_uavs):
        want = rec.inner.state_arrays()["q"][0, uav]
        with np.load(out / f"agent{uav}.npz") as ck:
            assert np.array_equal(ck["state.q"], want), uav
            assert not np.array_equal(want, state["q"][0, uav])  # it learned on from the trained table
    resim = [sys.executable, "-m", "truav.cli", "log", "resim", str(recording), "--agent", "truav", "--quiet"]
    done = subprocess.run(resim, capture_output=True, text=True, timeout=SWARM_TIMEOUT_S)
    assert done.returncode == 0, done.stdout + done.stderr


def test_a_swarm_refuses_a_start_state_of_another_class_or_size_in_one_line(tmp_path):
    agent_run = _train(tmp_path, "trained-api", "--agent", "truav")
    native_run = _train(tmp_path, "trained-native")
    scenario = tmp_path / "up.toml"
    scenario.write_text(to_toml(CFG))
    base = [sys.executable, "-m", "truav.cli.swarm", "up", "--lockstep", "--scenario", str(scenario), "--episodes",
            "1", "--out", str(tmp_path / "never"), "--quiet", "--no-plot"]
    for extra, words in ((["--agent", "random", "--qtable", str(agent_run)], "trained by agent 'truav', not 'random'"),
                         (["--agent", "truav", "--qtable", str(native_run)], "agent.npz"),
                         (["--agent", "truav", "--qtable", str(agent_run), "--agents", "3"], "this swarm flies 3"),
                         (["--scheme", "patrol", "--qtable", str(agent_run)], "--qtable")):
        done = subprocess.run(base + extra, capture_output=True, text=True, timeout=60)
        assert done.returncode == 2, (extra, done.stdout, done.stderr)
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1 and words in lines[0] and "Traceback" not in done.stderr, (extra, done.stderr)
        assert not (tmp_path / "never").exists()

"""The public agent API (agents/api.py): a user's class from outside the repository trains and evaluates
through the CLI; the built-in random and patrol agents through it; one line for every mistake."""

from __future__ import annotations

import dataclasses
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from truav.analysis import runio
from truav.analysis.agent_run import read_agent_state
from truav.cli import main as cli
from truav.config import Config
from tests.support.tutorial_agent import USER_MODULE

REPO = Path(__file__).resolve().parents[2]
TINY = ["--seeds", "1", "--episodes", "3", "--set", "scenario.n_vehicles=60", "--set",
        "scenario.steps_per_episode=10", "--set", "roads.warmup_steps=10", "--quiet"]
TINY_CFG = Config().replace(scenario={"n_vehicles": 60, "steps_per_episode": 10}, roads={"warmup_steps": 10})


BAD_MODULE = textwrap.dedent('''
    from agents.api import UavAgent

    class NoAct:
        api_version = 1
        def learn(self, view, reward, done): pass
        def state_dict(self): return {}
        def load_state_dict(self, d): pass

    class Future(UavAgent):
        api_version = 99
        def act(self, view): return 0

    class Boom(UavAgent):
        def __init__(self, cfg, uav, rng):
            raise RuntimeError("no GPU")

    class Illegal(UavAgent):
        def act(self, view):
            return 16 if view.step == 2 and self.uav == 3 else 0

    class Raises(UavAgent):
        def act(self, view): return 0
        def learn(self, view, reward, done):
            if view.step == 4:
                raise KeyError("lost")

    class Hangs(UavAgent):
        call_limit_s = 0.2
        def act(self, view):
            while view.step == 2 and self.uav == 1:
                pass
            return 0

    class SlowAtOnce(UavAgent):
        call_limit_s = 0.2
        def act(self, view):
            import time
            time.sleep(5)
            return 0

    class IllegalAtOnce(UavAgent):
        def act(self, view): return "north"

    class Swallows(UavAgent):
        call_limit_s = 0.2
        def act(self, view):
            try:
                while True:
                    pass
            except Exception:
                return 0

    class BadLimit(UavAgent):
        call_limit_s = 0
        def act(self, view): return 0
''')


def _metrics(run: Path) -> dict[str, np.ndarray]:
    return runio.read_metrics(run / runio.METRICS_FILE)[1]


def test_user_class_outside_the_repo_trains_and_evaluates(tmp_path):
    mods = tmp_path / "mylab"
    mods.mkdir()
    (mods / "bandit_agent.py").write_text(USER_MODULE)
    env = {**os.environ, "PYTHONPATH": f"{mods}{os.pathsep}{REPO}"}
    out = tmp_path / "run"
    train = subprocess.run([sys.executable, "-m", "truav.cli", "train", "--agent", "bandit_agent:Bandit", *TINY,
                            "--out", str(out)], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert train.returncode == 0, train.stderr
    assert {"metrics.csv", "convergence.png", "agent.npz", "config.toml"} <= {p.name for p in out.iterdir()}
    name, seeds, state, _ = read_agent_state(out)
    assert (name, seeds) == ("bandit_agent:Bandit", [0])
    # every UAV learned from every step of its 3 episodes x 10 steps (the count of greedy picks included)
    assert state["count"].shape == (1, 5, 16) and (state["count"].sum(axis=-1) == 30).all()
    assert np.isfinite(state["value"]).all() and state["value"].any()
    ev = subprocess.run([sys.executable, "-m", "truav.cli", "evaluate", str(out), "--episodes", "2", "--quiet",
                         "--against", "patrol"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert ev.returncode == 0, ev.stderr
    assert "bandit_agent:Bandit" in ev.stdout and "patrol" in ev.stdout


def test_random_agent_is_seeded(tmp_path):
    for name, start in (("a", "0"), ("b", "0"), ("c", "7")):
        assert cli.main(["train", "--agent", "random", *TINY, "--seed-start", start, "--out",
                         str(tmp_path / name)]) == 0
    a, b, c = (_metrics(tmp_path / n) for n in "abc")
    assert all(np.array_equal(a[k], b[k], equal_nan=True) for k in a)
    assert not np.array_equal(a["coverage_pct"], c["coverage_pct"])


def test_batched_form_equals_per_uav_form_and_patrol_equals_the_controller():
    from truav.analysis.trainer import run_chunk
    per_uav = run_chunk("agent:random", TINY_CFG, [0, 1], 3).metrics
    batched = run_chunk("agent:agents.random_agent:RandomAgentBatched", TINY_CFG, [0, 1], 3).metrics
    assert all(np.array_equal(per_uav[k], batched[k], equal_nan=True) for k in per_uav)
    api = run_chunk("agent:patrol", TINY_CFG, [0, 1], 3).metrics
    own = run_chunk("patrol", TINY_CFG, [0, 1], 3).metrics
    for k in ("coverage_pct", "pdr", "delay_ms", "energy_j", "delivered", "generated"):
        assert np.array_equal(api[k], own[k], equal_nan=True), k


@pytest.mark.parametrize("geofence", [False, True])
def test_truav_through_the_api_trains_what_truav_trains(geofence):
    """TRUAV's learner as an API class (agents/truav_agent.py, registered as `truav`): every metric of every
    episode and every Q-table entry equal to the trainer's own TRUAV, at the start of a training (epsilon
    high) and with the geofence the paper preset turns on."""
    from truav.analysis.trainer import run_chunk
    cfg = TINY_CFG.replace(learner={"geofence": geofence, "episodes": 6})
    own = run_chunk("truav", cfg, [0, 1], 6)
    api = run_chunk("agent:truav", cfg, [0, 1], 6)
    assert set(api.metrics) == set(own.metrics) - {"epsilon"}  # the trainer's own columns: its epsilon
    for k in api.metrics:
        assert np.array_equal(api.metrics[k], own.metrics[k], equal_nan=True), k
    assert np.array_equal(api.policy["q"], own.q)
    assert not np.array_equal(own.q, run_chunk("truav", cfg, [0, 1], 5).q)  # the last episode learned something


def test_truav_per_uav_stepped_and_whole_episode_forms_end_in_the_same_state():
    """TruavAgent's three forms (per UAV; batched, stepped; batched, whole episodes in TRUAV's fused kernel,
    what `truav train --agent truav` runs): every array of every UAV's state_dict equal after training,
    the same episodes' metrics, a greedy evaluation from that state equal, and a state saved by one form
    goes on in another exactly."""
    from agents.api_controller import ApiController
    from agents.truav_agent import TruavAgent, TruavBatched
    from truav.analysis.driver import run_episodes

    class PerUav(TruavAgent):
        batched = None

    class Stepped(TruavBatched):
        run_episode = None  # the driver then steps act/learn

    class SteppedAgent(TruavAgent):
        batched = Stepped

    cfg, seeds = TINY_CFG.replace(learner={"geofence": True}), [3, 8]
    forms = (PerUav, SteppedAgent, TruavAgent)
    ctls = [ApiController("truav", cls, cfg, seeds) for cls in forms]
    assert [c.fused for c in ctls] == [False, False, True]
    metrics = [run_episodes(cfg, seeds, c, 4) for c in ctls]
    states = [c.state_arrays() for c in ctls]
    for m, st in zip(metrics[1:], states[1:]):
        assert set(st) == set(states[0])
        for k, want in states[0].items():
            assert st[k].shape == want.shape and np.array_equal(st[k], want), k
        for k, want in metrics[0].items():
            assert np.array_equal(m[k], want, equal_nan=True), k
    greedy = [run_episodes(cfg, seeds, ApiController("truav", cls, cfg, seeds, train=False, state=states[0]), 2)
              for cls in forms]
    assert all(np.array_equal(g["coverage_pct"], greedy[0]["coverage_pct"]) for g in greedy[1:])
    # the per-UAV form's state loaded into the fused form learns on as the per-UAV form does (2 episodes more)
    on = [ApiController("truav", cls, cfg, seeds, state=states[0]) for cls in (PerUav, TruavAgent)]
    for c in on:
        run_episodes(cfg, seeds, c, 2)
    a, b = (c.state_arrays() for c in on)
    assert all(np.array_equal(a[k], b[k]) for k in a) and not np.array_equal(a["q"], states[0]["q"])


def test_truav_through_the_api_resumes_from_its_state_dict():
    """A TruavAgent rebuilt from another's state_dict mid-episode goes on as the original does."""
    from agents.truav_agent import TruavAgent
    from truav import seeding
    from truav.analysis.agent_loader import trial_view
    cfg = TINY_CFG
    a = TruavAgent(cfg, 0, seeding.agent_rng(0, 0))
    view = trial_view(cfg)
    a.begin_episode(0, True)
    a.act(view)
    b = TruavAgent(cfg, 0, seeding.agent_rng(9, 0))
    b.load_state_dict(a.state_dict())
    for step in range(1, 6):
        v = dataclasses.replace(view, step=step, pos=(view.pos[0] + 10 * step, view.pos[1]), vehicles_in_range=step)
        a.learn(v, 0.0, False)
        b.learn(v, 0.0, False)
        assert a.act(v) == b.act(v)
    assert all(np.array_equal(x, b.state_dict()[k]) for k, x in a.state_dict().items())


@pytest.fixture
def bad_module(tmp_path, monkeypatch):
    (tmp_path / "badagents.py").write_text(BAD_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    yield
    sys.modules.pop("badagents", None)


@pytest.mark.parametrize("agent, says", [
    ("nosuchmodule:Agent", "cannot import nosuchmodule"),
    ("badagents:Missing", "badagents has no Missing"),
    ("badagents:NoAct", "NoAct lacks the method act"),
    ("badagents:Future", "API version 99"),
    ("badagents:Boom", "Boom(cfg, uav, rng) raised RuntimeError: no GPU"),
    ("notregistered", "no agent registered under that name"),
    ("badagents:SlowAtOnce", "SlowAtOnce.act(view) took longer than 0.2 s (its call_limit_s)"),
    ("badagents:Swallows", "Swallows.act(view) took longer than 0.2 s (its call_limit_s)"),
    ("badagents:IllegalAtOnce", "act returned 'north' (str), not an int action"),
    ("badagents:BadLimit", "BadLimit.call_limit_s must be a number of seconds in (0, 60], got 0"),
])
def test_mistakes_are_one_line_before_the_start(bad_module, tmp_path, capsys, agent, says):
    out = tmp_path / "run"
    assert cli.main(["train", "--agent", agent, *TINY, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and agent in err and says in err, err
    assert not out.exists()


@pytest.mark.parametrize("agent, workers, says", [
    ("badagents:Illegal", "1", r"\(UAV 3 of seed 0\): act returned 16, not an action"),
    # each seed's worker fails: the first to tell the parent is named
    ("badagents:Illegal", "2", r"\(UAV 3 of seed [01]\): act returned 16, not an action"),
    ("badagents:Raises", "1", r"\(UAV 0 of seed 0\): learn raised KeyError: 'lost'"),
    ("badagents:Hangs", "1", r"\(UAV 1 of seed 0\): act took longer than 0.2 s \(its call_limit_s\)"),
    ("badagents:Hangs", "2", r"\(UAV 1 of seed [01]\): act took longer than 0.2 s \(its call_limit_s\)"),
])
def test_a_class_breaking_during_training_is_one_line_exit_1(bad_module, tmp_path, capsys, agent, workers, says):
    two_seeds = ["--seeds", "2", *TINY[2:]]  # with 2 workers: the failure comes from a worker process
    assert cli.main(["train", "--agent", agent, *two_seeds, "--workers", workers, "--out", str(tmp_path / "r")]) == 1
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and re.search(f"^truav: error: agent {agent} {says}", err), err


class Probe:
    """A duck-typed agent (no UavAgent base) that records the calls it gets."""

    api_version = 1

    def __init__(self, cfg, uav, rng):
        self.uav, self.calls, self.training = uav, [], None

    def begin_episode(self, episode, train):
        self.calls.append(("begin", episode, train))
        self.training = train

    def act(self, view):
        self.calls.append(("act", view.episode, view.step))
        assert view.uav == self.uav and [b.uav for b in view.beacons] == [u for u in range(5) if u != self.uav]
        return (self.uav + view.step) % 16

    def learn(self, view, reward, done):
        self.calls.append(("learn", view.episode, view.step, done))

    def beacon_fields(self):
        return {"uav_again": self.uav}

    def state_dict(self):
        return {"w": np.full(3, float(self.uav))}

    def load_state_dict(self, d):
        self.loaded = {k: np.array(v) for k, v in d.items()}


def test_the_calls_follow_the_documented_order_and_state_round_trips():
    from agents.api_controller import ApiController
    from truav.analysis.driver import run_episodes
    T, E = TINY_CFG.scenario.steps_per_episode, 2
    ctl = ApiController("probe", Probe, TINY_CFG, [0, 1])
    run_episodes(TINY_CFG, [0, 1], ctl, E)
    want = []
    for e in range(E):
        want += [("begin", e, True), ("act", e, 0)]
        for t in range(1, T + 1):
            want.append(("learn", e, t, t == T))
            if t < T:
                want.append(("act", e, t))
    assert all(a.calls == want for row in ctl.agents for a in row)
    assert ctl.views[1][2].beacons[0].fields == {"uav_again": 0}  # a peer's beacon fields, heard at the next step
    state = ctl.state_arrays()
    assert state["w"].shape == (2, 5, 3) and (state["w"][1, 4] == 4.0).all()
    greedy = ApiController("probe", Probe, TINY_CFG, [0, 1], train=False, state=state)
    assert np.array_equal(greedy.agents[1][3].loaded["w"], np.full(3, 3.0))
    run_episodes(TINY_CFG, [0, 1], greedy, 1)
    assert greedy.agents[0][0].calls[0] == ("begin", 0, False)


FAILS_ONCE = textwrap.dedent('''
    import os
    from agents.api import UavAgent

    class Picky(UavAgent):
        """Counts its steps; breaks in episode 4 while the file named by PICKY_BREAK exists."""
        def __init__(self, cfg, uav, rng):
            super().__init__(cfg, uav, rng)
            self.steps = 0
        def act(self, view):
            if view.episode == 4 and os.path.exists(os.environ.get("PICKY_BREAK", "")):
                raise ValueError("bug")
            return int(self.rng.integers(16))
        def learn(self, view, reward, done):
            self.steps += 1
        def state_dict(self):
            return {"steps": self.steps}
        def load_state_dict(self, d):
            self.steps = int(d["steps"])

    class Unpicklable(Picky):
        def __init__(self, cfg, uav, rng):
            super().__init__(cfg, uav, rng)
            self.callback = lambda: None
''')


@pytest.mark.parametrize("workers", ["1", "2"])
def test_a_class_breaking_during_training_stops_resumably(tmp_path, monkeypatch, capsys, workers):
    """A class that breaks mid-training stops with one line; fixed, the same command with --resume ends where
    an unbroken training ends, file for file."""
    (tmp_path / "picky.py").write_text(FAILS_ONCE)
    monkeypatch.syspath_prepend(str(tmp_path))
    flag = tmp_path / "break"
    monkeypatch.setenv("PICKY_BREAK", str(flag))
    args = ["train", "--agent", "picky:Picky", "--seeds", "2", "--episodes", "6", *TINY[4:], "--workers", workers,
            "--checkpoint-every", "0.000001"]
    try:
        assert cli.main([*args, "--out", str(tmp_path / "whole")]) == 0
        flag.touch()
        assert cli.main([*args, "--out", str(tmp_path / "cut")]) == 1
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and "act raised ValueError: bug" in err and "--resume" in err, err
        kept = int(re.search(r"\((\d+) of 6 episodes", err).group(1))
        # One worker: it breaks in episode 4, checkpointed to its start. Two: the other chunk ends the
        # episode it is in and checkpoints it (wherever its own load put it), never less than one episode.
        assert kept == 4 if workers == "1" else 1 <= kept <= 4, err
        flag.unlink()  # the fix
        assert cli.main([*args, "--out", str(tmp_path / "cut"), "--resume"]) == 0
        for name in ("metrics.csv", "agent.npz"):
            assert (tmp_path / "cut" / name).read_bytes() == (tmp_path / "whole" / name).read_bytes(), name
        assert not (tmp_path / "cut" / "resume").exists()
        # a class whose instances do not pickle trains, without checkpoints, and says so
        assert cli.main([*args[:2], "picky:Unpicklable", *args[3:], "--out", str(tmp_path / "u")]) == 0
        assert "note: --agent picky:Unpicklable: its instances cannot be pickled" in capsys.readouterr().err
    finally:
        sys.modules.pop("picky", None)


def test_a_user_class_is_a_scheme_of_the_velocity_experiment(tmp_path):
    """`truav experiment velocity --schemes pkg.module:Class`: trained, evaluated greedily on held-out traffic,
    in the tables and figures beside the built-in schemes; a second run resumes its finished cells."""
    mods = tmp_path / "mylab"
    mods.mkdir()
    (mods / "bandit_agent.py").write_text(USER_MODULE)
    env = {**os.environ, "PYTHONPATH": f"{mods}{os.pathsep}{REPO}"}
    out = tmp_path / "vel"
    cmd = [sys.executable, "-m", "truav.cli", "experiment", "velocity", "--quick", "--speeds", "15", "--schemes",
           "bandit_agent:Bandit", "patrol", "--workers", "2", "--quiet", "--out", str(out)]
    first = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert first.returncode == 0, first.stderr
    rows = (out / "summary.csv").read_text().splitlines()
    assert any(r.startswith("bandit_agent:Bandit,") for r in rows) and any(r.startswith("patrol,") for r in rows)
    assert "| bandit_agent:Bandit | 15 |" in (out / "summary.md").read_text()
    assert len(list((out / "cells").glob("bandit_agent-Bandit_v15_*.npz"))) == 1
    again = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0 and "2 cells, 2 already finished, 0 to run" in again.stdout, again.stdout


@pytest.mark.parametrize("agent, says", [("badagents:Boom", "Boom(cfg, uav, rng) raised RuntimeError: no GPU"),
                                         ("nosuch", "no agent registered under that name")])
def test_a_bad_scheme_of_the_velocity_experiment_is_one_line(bad_module, tmp_path, capsys, agent, says):
    out = tmp_path / "vel"
    assert cli.main(["experiment", "velocity", "--quick", "--schemes", "truav", agent, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and f"--schemes {agent}: {says}" in err, err
    assert not out.exists()

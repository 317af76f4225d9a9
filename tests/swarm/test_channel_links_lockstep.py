"""Channel-driven beacon links (links.model = "channel") in a lock-step swarm: the agents lose the beacons
the in-process trainer loses, so their Q-tables equal `truav train`'s entry for entry, in a scenario where
the channel really drops some (UAVs a few hundred metres apart, 50% range 1882 m at noise 1e-12 W)."""

from __future__ import annotations

import json

import numpy as np

from tests.support.lockstep import CFG, SEED, agent_tables, run_swarm
from truav.analysis.trainer import run_chunk


def test_lockstep_swarm_with_channel_links_equals_the_trainer(tmp_path):
    cfg = CFG.replace(scenario={"n_uavs": 3}, learner={"episodes": 6}, links={"model": "channel"},
                      channel={"noise_w": 1e-12})
    expected = run_chunk("truav", cfg, [SEED], cfg.learner.episodes)
    ideal = run_chunk("truav", cfg.replace(links={"model": "ideal"}), [SEED], cfg.learner.episodes)
    assert not np.array_equal(expected.q, ideal.q)  # the lost beacons change what the trainer learns
    out = run_swarm(tmp_path, "channel-links", cfg=cfg)
    q, steps = agent_tables(out, cfg)
    assert steps == [cfg.learner.episodes * cfg.scenario.steps_per_episode] * cfg.scenario.n_uavs
    assert np.array_equal(q, expected.q[0])
    heard = lost = 0
    per_agent = cfg.learner.episodes * (cfg.scenario.steps_per_episode + 1) * (cfg.scenario.n_uavs - 1)
    for i in range(cfg.scenario.n_uavs):
        stats = json.loads((out / f"agent{i}.json").read_text())
        assert stats["lockstep"]["decisions_without_peer"] == 0  # a lost beacon is decided, not waited for
        links = stats["channel_links"]
        assert sum(c["heard"] + c["lost"] for c in links.values()) == per_agent  # every beacon decided once
        heard += sum(c["heard"] for c in links.values())
        lost += sum(c["lost"] for c in links.values())
    assert heard > 0 and lost > 0, (heard, lost)


def test_lockstep_federated_swarm_with_channel_links_equals_the_trainer(tmp_path):
    """Federated TRUAV's shares ride the same links: a share the channel loses is not merged, in the swarm
    as in the trainer, and the Q-tables agree entry for entry."""
    cfg = CFG.replace(scenario={"n_uavs": 3}, learner={"episodes": 6}, links={"model": "channel"},
                      channel={"noise_w": 1e-12}, federated={"every": 1})
    expected = run_chunk("truav", cfg, [SEED], cfg.learner.episodes)
    out = run_swarm(tmp_path, "channel-fed", cfg=cfg)
    q, _ = agent_tables(out, cfg)
    assert np.array_equal(q, expected.q[0])
    merged = lost = 0
    for i in range(cfg.scenario.n_uavs):
        fed = json.loads((out / f"agent{i}.json").read_text())["federated"]
        assert not fed["missing"] and not fed["refused"]
        merged += fed["shares_merged"]
        lost += sum(fed.get("channel_lost", {}).values())
    assert merged + lost == cfg.learner.episodes * 3 * 2  # every peer's share of every round decided once
    assert merged > 0 and lost > 0, (merged, lost)


def test_realtime_per_link_delivery_matches_the_model(tmp_path):
    """A real-time run (20 Hz): each directed link's delivered beacon count is within four standard deviations
    (plus one for the count's discreteness) of the model's prediction, the sum of P_deliver over the beacons the
    receiver decided on, at the distances it decided them by."""
    import sys

    from tests.support.runs import run_to_end
    from truav.config import to_toml
    cfg = CFG.replace(scenario={"n_uavs": 3}, learner={"episodes": 6}, links={"model": "channel"},
                      channel={"noise_w": 1e-12})
    scenario = tmp_path / "rt.toml"
    scenario.write_text(to_toml(cfg))
    out = tmp_path / "rt"
    cmd = [sys.executable, "-m", "truav.cli.swarm", "up", "--scheme", "truav", "--rate", "20", "--seed", str(SEED), "--run", "rt",
           "--episodes", str(cfg.learner.episodes), "--scenario", str(scenario), "--out", str(out), "--quiet",
           "--no-plot"]
    assert run_to_end(cmd, tmp_path / "rt.log", 180.0) == 0, (tmp_path / "rt.log").read_text(errors="replace")
    decided = 0
    for i in range(cfg.scenario.n_uavs):
        links = json.loads((out / f"agent{i}.json").read_text())["channel_links"]
        assert sorted(links) == [str(j) for j in range(cfg.scenario.n_uavs) if j != i]
        for j, c in links.items():
            decided += c["heard"] + c["lost"]
            assert abs(c["heard"] - c["expected"]) <= 4.0 * c["variance"] ** 0.5 + 1.0, (i, j, c)
    assert decided >= cfg.learner.episodes * cfg.scenario.steps_per_episode * 6 // 2  # most beacons came in time

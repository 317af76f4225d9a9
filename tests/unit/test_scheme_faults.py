"""The comparative stress test's plans and rows (`truav experiment faults --schemes ...`); the swarm
runs themselves are those of tests/swarm/test_schemes_lockstep.py and tests/swarm/test_controller_faults.py."""

import tomllib

import pytest

from truav.faults import check_plan_for, plan_from_dict
from truav.swarm import scheme_faults as cmp


def plan(scheme, kind, level, run_s=10.0):
    return check_plan_for(plan_from_dict(tomllib.loads(cmp.plan_text(scheme, kind, level, run_s))), 5,
                          scheme=scheme)


def test_every_scheme_meets_the_same_link_faults_and_its_own_crash():
    for kind in ("loss", "latency"):
        plans = [plan(s, kind, 0.3 if kind == "loss" else 200.0) for s in cmp.SCHEMES]
        assert plans[0] == plans[1] == plans[2]  # one plan: beacons, uplink and downlink alike
        assert {f.params["keys"] for f in plans[0].faults} == set(cmp.LINK_KEYS)
    truav, central = plan("truav", "crash", 0.4), plan("central", "crash", 0.4)
    assert truav.faults[0].params == {"uav": 0, "restart_after": 4.0} and truav.faults[0].start == 2.0
    assert central.faults[0].params == {"target": "controller", "restart_after": 4.0}
    assert "restart_after" not in plan("central", "crash", 0.8).faults[0].params  # down to the end
    assert cmp.plan_text("patrol", "loss", 0.0, 10.0) == ""


def test_points_share_one_baseline_per_scheme_and_rows_count_missed_decisions():
    size = cmp.SIZES["quick"]
    pts = cmp.points(size, ("truav", "central"))
    assert pts.count(("central", "none", 0.0)) == 1 and len(pts) == 2 * 9
    summary = {"world": {"episodes": [{"coverage_pct": 10.0, "pdr": 0.5, "delay_ms": 3.0, "energy_j": 1e3}],
                         "ticks": 11, "deadline_misses": 2, "hover_answers": 3},
               "agents": [{"commands": {"fresh": 5, "held": 1, "hovered": 3}}, {"commands": {"held": 4}}]}
    row = cmp.row_of("central", "crash", 0.4, summary, 2)
    assert row["missed_actions"] == pytest.approx((2 + 3 + 5) / 20)
    assert row["coverage_pct"] == 10.0


def test_the_learning_variants_fly_the_truav_table_online_with_and_without_sharing(tmp_path, monkeypatch):
    """federated and truav_online: scheme truav, the trained table, learning (not greedy), over several
    episodes; only federated shares (every 1 unless the config says), and the planned faults reach its
    shares' keys and last as long as its longer run."""
    import json

    from truav.config import Config
    from truav.swarm import supervisor
    seen = {}

    def fake_run_swarm(cfg, opts):
        seen[opts.out.rsplit("/", 1)[-1]] = (cfg, opts)
        (tmp_path / opts.out.rsplit("/", 1)[-1]).mkdir()
        (tmp_path / opts.out.rsplit("/", 1)[-1] / "summary.json").write_text(json.dumps(  # a finished run's
            {"interrupted": False, "outcome": {"result": "ok"}, "world": {"episodes": [{}] * opts.episodes}}))
        return 0

    monkeypatch.setattr(supervisor, "run_swarm", fake_run_swarm)
    size = cmp.SIZES["quick"]
    policies = {"truav": "runs/policy", "central": None}
    for scheme in ("federated", "truav_online", "truav"):
        cmp.run_point(Config(), tmp_path, 3, policies, 10.0, size, 1, 0, scheme, "crash", 0.4)
    fed_cfg, fed = seen["federated-crash-0.4"]
    online_cfg, online = seen["truav_online-crash-0.4"]
    greedy_cfg, greedy = seen["truav-crash-0.4"]
    assert fed.scheme == online.scheme == "truav" and fed.qtable == online.qtable == "runs/policy"
    assert not fed.greedy and not online.greedy and greedy.greedy
    assert fed.episodes == online.episodes == size.learn_episodes > greedy.episodes == size.episodes
    assert fed_cfg.federated.every == 1 and online_cfg.federated.every == 0 and greedy_cfg.federated.every == 0
    # going on from the trained table, exploring as its training ended (episode 0 of a swarm is not the table's)
    assert fed_cfg.learner.epsilon_start == online_cfg.learner.epsilon_end == Config().learner.epsilon_end
    assert greedy_cfg.learner.epsilon_start == Config().learner.epsilon_start
    crash = tomllib.loads((tmp_path / "federated-crash-0.4.toml").read_text())["fault"][0]
    assert crash["restart_after"] == pytest.approx(0.4 * cmp.run_seconds(size, 10.0, "federated"))
    every3 = Config().replace(federated={"every": 3})
    cmp.run_point(every3, tmp_path, 3, policies, 10.0, size, 1, 0, "federated", "loss", 0.25)
    assert seen["federated-loss-0.25"][0].federated.every == 3
    loss = tomllib.loads((tmp_path / "federated-loss-0.25.toml").read_text())["fault"]
    assert {f["keys"] for f in loss} >= {"uav/*/qshare/*", "uav/*/beacon"}


def test_rows_count_the_federated_shares_and_zero_for_the_others():
    summary = {"world": {"episodes": [{"coverage_pct": 10.0, "pdr": 0.5, "delay_ms": 3.0, "energy_j": 1e3}],
                         "ticks": 3},
               "agents": [{"federated": {"shares_sent": 2, "shares_merged": 3, "refused": {"stale": 1, "nan": 2},
                                         "missing": 1}},
                          {"federated": {"shares_sent": 2, "shares_merged": 1, "refused": {}, "missing": 0}}]}
    row = cmp.row_of("federated", "loss", 0.25, summary, 2)
    assert [row[c] for c in cmp.FEDERATED_COLUMNS] == [4, 4, 3, 1]
    plain = cmp.row_of("truav", "loss", 0.25, {"world": {"episodes": [], "ticks": 0}, "agents": [{}]}, 2)
    assert [plain[c] for c in cmp.FEDERATED_COLUMNS] == [0, 0, 0, 0]


def test_the_faults_command_takes_the_learning_variants_and_refuses_others():
    from truav.cli.main import build_parser
    parser = build_parser()
    args = parser.parse_args(["experiment", "faults", "--quick", "--schemes", "federated", "truav_online"])
    assert args.schemes == ["federated", "truav_online"]



def test_the_faults_command_takes_an_agent_class_and_names_one_it_cannot_load(tmp_path, capsys):
    """Any other --schemes name is an agent class: found and checked before anything runs, or one line, exit 2."""
    from truav.cli.main import build_parser, main
    args = build_parser().parse_args(["experiment", "faults", "--quick", "--schemes", "random", "pkg.mod:Cls"])
    assert args.schemes == ["random", "pkg.mod:Cls"]
    out = tmp_path / "never"
    assert main(["experiment", "faults", "--quick", "--schemes", "truav", "fedavg", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--schemes fedavg" in err[0], err
    assert not out.exists()
    assert cmp.is_agent_class("agents.random_agent:RandomAgent") and not cmp.is_agent_class("federated")
    assert cmp.file_name("agents.random_agent:RandomAgent") == "agents.random_agent-RandomAgent"


def test_partitions_cut_the_first_uavs_off_the_rest_for_a_share_of_the_run_and_are_a_kind_of_every_size():
    """kind partition: UAVs 0..n//2-1 cannot hear the others (under central, nor the controller, which stays with
    the rest), from CRASH_AT of the run for ``level`` of it (to the end at 0.8); the sizes sweep it like the crash."""
    truav = plan("truav", "partition", 0.4)
    assert [f.kind for f in truav.faults] == ["partition"] and truav.faults[0].start == 2.0
    assert truav.faults[0].duration == pytest.approx(4.0)
    assert truav.faults[0].params["groups"] == [[0, 1], [2, 3, 4]]
    central = plan("central", "partition", 0.8)
    assert central.faults[0].params["groups"] == [[0, 1], ["controller", 2, 3, 4]]
    assert central.faults[0].duration == float("inf")  # to the end of the run
    assert cmp.plan_text("spread", "partition", 0.0, 10.0) == ""
    assert "partition" in [k for k, _, _ in cmp.KINDS]
    for size in cmp.SIZES.values():
        pts = cmp.points(size, ("ppo",))
        assert [lv for s, k, lv in pts if k == "partition"] == [x for x in size.partition_share if x > 0] != []


def test_a_comparison_takes_a_size_of_its_own(tmp_path, monkeypatch):
    """run_comparison(size=CompareSize(...)): a docs script sizes its runs (seeds x a few levels) itself."""
    import json

    from truav.config import Config
    from truav.swarm import supervisor
    names = []

    def fake_run_swarm(cfg, opts):
        name = opts.out.rsplit("/", 1)[-1]
        names.append(name)
        (tmp_path / name).mkdir()
        (tmp_path / name / "summary.json").write_text(json.dumps(
            {"interrupted": False, "outcome": {"result": "ok"},
             "world": {"episodes": [{"coverage_pct": 1.0, "pdr": 0.1, "delay_ms": 1.0, "energy_j": 1.0}] * opts.episodes,
                       "ticks": 10}}))
        return 0

    monkeypatch.setattr(supervisor, "run_swarm", fake_run_swarm)
    size = cmp.CompareSize((0.0, 0.5), (0.0,), (0.0,), 1, 20, {"truav": 1, "central": 1}, 1, partition_share=(0.0, 0.8))
    cmp.run_comparison(Config(), size, tmp_path, ("patrol",), seed=2)
    assert sorted(names) == ["patrol-loss-0.5", "patrol-none-0", "patrol-partition-0.8"]
    rows = (tmp_path / "comparison.csv").read_text().splitlines()
    assert sum(r.startswith("patrol,partition,") for r in rows) == 2  # the baseline and the partition

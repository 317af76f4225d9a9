"""Router-side rate caps under --secure (truav.bus.security.rate_caps): the router's config caps every
key a real-time run sends at the rate it needs times a margin, and the router drops a flood on a key
beyond its cap while paced traffic passes whole. Loopback only; the flood is bounded in count."""

from __future__ import annotations

import json
import threading
import time

import zenoh

from tests.support.waits import free_port, wait_matched
from truav.bus import security
from truav.bus.rate_caps import MIN_CAP_HZ
from truav.swarm.supervisor import SwarmOptions
from truav.wire import keys
from truav.wire.schema import HEALTH_PERIOD_S, REJECTION_PERIOD_S

RUN = "caps"
N = 3
RATE_HZ = 10.0
M = security.RATE_CAP_MARGIN


def _caps_in(router_json5) -> dict[str, float]:
    conf = json.loads(router_json5.read_text())
    [item] = conf["downsampling"]
    assert item["flows"] == ["ingress"] and item["messages"] == ["put"]
    return {r["key_expr"]: r["freq"] for r in item["rules"]}


def test_router_config_caps_every_key_of_a_realtime_run(tmp_path) -> None:
    opts = SwarmOptions(run=RUN, rate_hz=RATE_HZ, beacon_every=10, secure=True)
    security.secure_setup(tmp_path, opts, N, f"tcp/127.0.0.1:{free_port()}")
    caps = _caps_in(tmp_path / "creds" / security.ROUTER_CONFIG)
    tick = RATE_HZ * M
    expected = {keys.world_tick(RUN): tick, keys.world_positions(RUN): tick, keys.metrics_step(RUN): tick,
                keys.metrics_episode(RUN): tick, keys.world_snapshot(RUN): M * MIN_CAP_HZ}
    for i in range(N):
        expected |= {keys.uav_obs(RUN, i): tick, keys.uav_action(RUN, i): tick, keys.uav_state(RUN, i): tick,
                     keys.controller_cmd(RUN, i): tick, f"{keys.uav_beacon(RUN, i)}/**": RATE_HZ / 10 * M,
                     keys.uav_health(RUN, i): M / HEALTH_PERIOD_S, keys.uav_rejected(RUN, i): M / REJECTION_PERIOD_S,
                     keys.uav_qshares(RUN, i): M * MIN_CAP_HZ, keys.uav_snapshot(RUN, i): M * MIN_CAP_HZ}
    assert caps == expected
    # Every key a run sends is capped (by exactly one rule), but the supervisor's control and faults
    # (rare and bursty) and the replay's own run; and each put pattern of the ACL stands for some of them.
    sent = [keys.world_tick(RUN), keys.world_positions(RUN), keys.metrics_step(RUN), keys.metrics_episode(RUN),
            keys.world_snapshot(RUN)]
    for i in range(N):
        sent += [keys.uav_obs(RUN, i), keys.uav_beacon(RUN, i), keys.uav_beacon_in_cell(RUN, i, (2, 3)),
                 keys.uav_action(RUN, i), keys.uav_state(RUN, i), keys.uav_health(RUN, i), keys.controller_cmd(RUN, i),
                 keys.uav_rejected(RUN, i), keys.uav_qshare(RUN, i, 0), keys.uav_qshare(RUN, i, 2),
                 keys.uav_snapshot(RUN, i)]
    for key in sent:
        assert sum(security._matches(key, rule) for rule in caps) == 1, key
    uncapped = {keys.all_control(RUN), keys.all_faults(RUN), keys.control(RUN, "shutdown"),
                keys.all_overrides(RUN), keys.fault(RUN, "override")}  # a UAV steered from outside: rare, bursty
    for g in security.grants(RUN, N):
        for put in g.put:
            if put not in uncapped and not put.startswith(keys.prefix(security.replay_run(RUN))):
                assert any(security._matches(k, put) for k in sent), f"{g.identity} may put on {put}: not capped"


def test_lockstep_router_has_no_caps(tmp_path) -> None:
    """Lock-step ticks as fast as the processes answer: no rate to cap at."""
    security.secure_setup(tmp_path, SwarmOptions(run=RUN, lockstep=True, secure=True), N,
                          f"tcp/127.0.0.1:{free_port()}")
    assert "downsampling" not in json.loads((tmp_path / "creds" / security.ROUTER_CONFIG).read_text())


def test_router_drops_a_flood_beyond_the_cap_and_passes_paced_traffic(tmp_path) -> None:
    ep = f"tcp/127.0.0.1:{free_port()}"
    d = security.issue(tmp_path / "creds", RUN, N, ep, caps=security.rate_caps(RUN, N, RATE_HZ))
    creds = security.load(d, RUN)
    cap = RATE_HZ * M
    router = zenoh.open(zenoh.Config.from_file(str(d / security.ROUTER_CONFIG)))
    sessions = []
    try:
        recorder, agent1, agent0 = (zenoh.open(zenoh.Config.from_file(str(creds.config_file(who))))
                                    for who in (security.RECORDER, "uav/1", "uav/0"))
        sessions = [recorder, agent1, agent0]
        got: dict[str, list[float]] = {"beacon": [], "action": []}
        lock = threading.Lock()

        def heard(what: str):
            def on_sample(_sample) -> None:
                with lock:
                    got[what].append(time.monotonic())
            return on_sample

        recorder.declare_subscriber(keys.uav_beacon(RUN, 1), heard("beacon"))
        recorder.declare_subscriber(keys.uav_action(RUN, 0), heard("action"))
        assert wait_matched(agent0, keys.uav_action(RUN, 0)) and wait_matched(agent1, keys.uav_beacon(RUN, 1))
        paced = threading.Thread(target=lambda: [(agent0.put(keys.uav_action(RUN, 0), b"a"), time.sleep(1 / RATE_HZ))
                                                 for _ in range(10)])
        paced.start()
        flood_n, t0 = 0, time.monotonic()
        while time.monotonic() - t0 < 1.0 and flood_n < 20_000:  # agent 1, compromised, floods its own beacon key
            agent1.put(keys.uav_beacon(RUN, 1), b"x" * 64)
            flood_n += 1
            time.sleep(0.0002)
        paced.join()
        time.sleep(1.0)  # what the router let through has arrived
        with lock:
            beacons, actions = list(got["beacon"]), list(got["action"])
    finally:
        for s in sessions:
            s.close()
        router.close()
    assert len(actions) == 10, "paced traffic at the rate the run needs must pass whole"
    assert beacons, "the cap lets some of the flood through"
    span = beacons[-1] - t0
    # At most one put per 1/cap s got through the router, however slow this machine is.
    assert len(beacons) <= cap * span + 2, (len(beacons), span)
    assert len(beacons) < flood_n / 3, (len(beacons), flood_n)

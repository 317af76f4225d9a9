"""Rate caps of a real-time secure swarm: Zenoh's ``downsampling`` section, a maximum put rate per key
and session, derived from the rates the run needs (``truav-swarm up --secure``)."""

from __future__ import annotations

from collections.abc import Sequence

from truav.wire import keys
from truav.wire.schema import HEALTH_PERIOD_S, REJECTION_PERIOD_S

RATE_CAP_MARGIN = 20.0
"""Each key's cap is this many times the rate the run needs on it. Zenoh's downsampler is a minimum
interval per key and session (a put less than 1/cap after the last one passed is dropped), not a
bucket, so the margin covers bursts: a late world or agent catching up sends two ticks' messages a
few ms apart (5 ms at 10 Hz stays allowed); a flood is cut to 200 puts/s per key from thousands."""
DOWNSAMPLING_ID = "truav-rate-caps"


MIN_CAP_HZ = 1.0 / 60.0
"""The least rate a key is given: a federated Q share's part key without sharing (or sharing rarer than this),
the state snapshot keys (lock-step only) in real time."""


def rate_caps(run: str, n_uavs: int, rate_hz: float, beacon_every: int = 1,
              share_every_ticks: int = 0) -> tuple[tuple[str, float], ...]:
    """(key expression, puts/s) the router lets each session send on each key of a real-time run at
    ``rate_hz``: the rate the schema needs there (one per tick; beacons every ``beacon_every`` ticks;
    health every schema.HEALTH_PERIOD_S, rejections every REJECTION_PERIOD_S; each part key of a federated
    Q share once every ``share_every_ticks`` ticks, at least MIN_CAP_HZ) times RATE_CAP_MARGIN. Control and
    fault keys (the supervisor's, rare and bursty: several faults at one instant; the operator's overrides and
    the world's override events likewise) are not capped: the world keeps one pending override per UAV."""
    share_hz = max(rate_hz / share_every_ticks if share_every_ticks > 0 else 0.0, MIN_CAP_HZ)
    per_tick = (keys.world_tick(run), keys.world_positions(run), keys.metrics_step(run), keys.metrics_episode(run))
    needed: list[tuple[str, float]] = [(k, rate_hz) for k in per_tick]
    # State snapshots are lock-step only (--snapshot-every), where nothing is capped: in real time a put
    # there is never needed, so those keys get the least rate.
    needed.append((keys.world_snapshot(run), MIN_CAP_HZ))
    for i in range(n_uavs):
        needed += [(keys.uav_obs(run, i), rate_hz),
                   (f"{keys.uav_beacon(run, i)}/**", rate_hz / beacon_every),  # range-limited ones too
                   (keys.uav_action(run, i), rate_hz), (keys.uav_state(run, i), rate_hz),
                   (keys.uav_health(run, i), 1.0 / HEALTH_PERIOD_S), (keys.controller_cmd(run, i), rate_hz),
                   (keys.uav_rejected(run, i), 1.0 / REJECTION_PERIOD_S),
                   (keys.uav_qshares(run, i), share_hz),  # per part key, as the beacon cells are
                   (keys.uav_snapshot(run, i), MIN_CAP_HZ)]
    return tuple((k, hz * RATE_CAP_MARGIN) for k, hz in needed)


def downsampling_config(caps: Sequence[tuple[str, float]]) -> list[dict]:
    """Zenoh's ``downsampling`` section: ``caps`` applied to what each session puts (ingress), so an
    identity flooding its own keys gets its cap, per key, and no more through the router."""
    return [{"id": DOWNSAMPLING_ID, "flows": ["ingress"], "messages": ["put"],
             "rules": [{"key_expr": k, "freq": float(hz)} for k, hz in caps]}]


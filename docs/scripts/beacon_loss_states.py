"""How often beacon loss changes a greedy TRUAV decision (docs/fault-comparison.md, "Beacon loss").

In process, no bus: the world and greedy agents of `truav experiment faults`, except
that each agent builds its state from the beacons the sweep's link filter
(truav.bus.fault_filter.PlanFilter, plan ``keys = "uav/*/beacon"``) lets through, keeping each
peer's freshest beacon for at most agents.process.agent_process.REALTIME_BEACON_MAX_AGE_TICKS
ticks as a real-time agent does. Counts beacons heard, decisions whose state differs
from the state with every beacon, and greedy actions that differ.

    python docs/scripts/beacon_loss_states.py RUN [--steps 60] [--episodes 1]
"""

from __future__ import annotations

import argparse
import tomllib

import numpy as np

from agents.controller import TruavController
from agents.process.agent_process import REALTIME_BEACON_MAX_AGE_TICKS
from agents.state import all_peers, neighbour_features
from truav.analysis import runio
from truav.analysis.driver import run_episodes
from truav.bus.fault_filter import PlanFilter
from truav.faults import plan_from_dict
from truav.swarm.fault_sweep import plan_text


class LossyBeacons(TruavController):
    """Greedy agents (one env) whose neighbour features come from the beacons a PlanFilter passes."""

    def __init__(self, cfg, q, loss: float):
        super().__init__(cfg, [0], train=False, q=q)
        self.fused = False  # step through act/observe so _features is ours
        plan = plan_from_dict(tomllib.loads(plan_text("loss", loss)))  # the sweep's plan for this level
        self.filter = PlanFilter(plan, "sweep", t0_ns=0)
        U = cfg.scenario.n_uavs
        self.heard_pos = np.zeros((U, U, 2))
        self.heard_tick = np.full((U, U), -10**9)
        self.tick = 0
        self.where = []
        self.sent = self.heard = self.decisions = self.states_differ = self.actions_differ = 0

    def _features(self, obs):
        pos = obs.pos[0]
        U = pos.shape[0]
        for j in range(U):  # peer j's beacon of this tick, to every receiver i
            for i in range(U):
                if i == j:
                    continue
                self.sent += 1
                ok, _ = self.filter.decide(f"truav/sweep/uav/{j}/beacon", f"uav/{j}", f"uav/{i}",
                                           int(self.tick * 1e8))
                if ok:
                    self.heard += 1
                    self.heard_pos[i, j], self.heard_tick[i, j] = pos[j], self.tick
        fresh = self.heard_tick >= self.tick - REALTIME_BEACON_MAX_AGE_TICKS
        np.fill_diagonal(fresh, False)
        peers, heard = self.heard_pos[None], fresh[None]
        nearest, overlap = neighbour_features(obs.pos, peers, heard, self.cfg.scenario.comm_range_m)
        state = self.encoder.encode(obs.pos, obs.vehicles_in_range, obs.queued, nearest,
                                    self.encoder.neighbour_sectors(obs.pos, peers, heard), obs.densest_sector)
        full, _ = super()._features(obs)
        self.decisions += state.size
        really, _ = neighbour_features(obs.pos, *all_peers(obs.pos), self.cfg.scenario.comm_range_m)
        for u in np.flatnonzero(state[0] != full[0]):
            self.where.append((self.tick, int(u), float(nearest[0, u]), float(really[0, u])))
        self.states_differ += int((state != full).sum())
        self.actions_differ += int((self.learners.greedy(state, obs.pos) != self.learners.greedy(full, obs.pos)).sum())
        self.tick += 1
        return state, overlap


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("run")
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--episodes", type=int, default=1)
    ap.add_argument("--levels", type=float, nargs="+", default=[0.0, 0.25, 0.5])
    a = ap.parse_args()
    cfg = runio.read_config(a.run).replace(scenario={"steps_per_episode": a.steps})
    _, q = runio.read_qtables(a.run)
    q = q[:1]
    print("loss  heard/sent  states differ  greedy actions differ  coverage %  PDR %")
    for p in a.levels:
        c = LossyBeacons(cfg, q, p)
        m = run_episodes(cfg, [0], c, a.episodes)
        print(f"{p:4.2f}  {c.heard}/{c.sent} ({100 * c.heard / c.sent:.1f}%)  {c.states_differ}/{c.decisions}"
              f"  {c.actions_differ}  {m['coverage_pct'].mean():.3f}  {100 * m['pdr'].mean():.3f}")
        for tick, u, lossy_m, full_m in c.where:
            print(f"      tick {tick} uav {u}: nearest neighbour heard at {lossy_m:.0f} m, really at {full_m:.0f} m")


if __name__ == "__main__":
    main()

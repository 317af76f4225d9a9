"""The world's observation messages, built from the model's observation (pure: no bus).

The world process publishes exactly these (world.process.world_process.publish_round), and the re-simulation of a
recording (recorder.resim) builds them the same way, so a re-simulated observation is what the process
would have sent, field for field."""

from __future__ import annotations

from truav.config import Config
from truav.wire import schema


def observation_messages(cfg: Config, tick: int, episode: int, obs, done: bool) -> list[schema.Obs]:
    """Every UAV's observation of ``tick`` (environment 0 of the model's LocalObs ``obs``), in UAV order."""
    sc = cfg.scenario
    # Every column converted once (tolist: the same Python ints and floats as int()/float() per element): at
    # 100 UAVs the per-element numpy reads were most of a round's cost.
    pos, in_range, queued = obs.pos[0].tolist(), obs.vehicles_in_range[0].tolist(), obs.queued[0].tolist()
    relayed, covered, energy = obs.relayed[0].tolist(), obs.covered[0].tolist(), obs.energy_j[0].tolist()
    densest, exclusive = obs.densest_sector[0].tolist(), obs.exclusive[0].tolist()
    disc = obs.disc_offset[0].tolist() if obs.disc_offset is not None else [[0.0, 0.0]] * sc.n_uavs
    disc_n = obs.disc_vehicles[0].tolist() if obs.disc_vehicles is not None else [0] * sc.n_uavs
    return [schema.Obs(
        tick=tick, episode=episode, uav=i, pos=(float(pos[i][0]), float(pos[i][1])),
        vehicles_in_range=int(in_range[i]), queued_packets=int(queued[i]), relayed=int(relayed[i]),
        covered=int(covered[i]), energy_j=float(energy[i]), speed_max=sc.uav_speed_mps, done=done,
        densest_sector=int(densest[i]), exclusive=int(exclusive[i]), disc_offset=(float(disc[i][0]), float(disc[i][1])),
        disc_vehicles=int(disc_n[i])) for i in range(sc.n_uavs)]


__all__ = ["observation_messages"]

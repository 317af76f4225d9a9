"""Every parameter of a TRUAV run, with the paper's Table "Simulation
Parameters" as defaults.

One frozen dataclass per section; a docstring under each field says what it
is and, where the paper is silent, which source the default comes from.
`load_config` reads TOML (sections named like the dataclass fields of
`Config`), rejects unknown keys and out-of-range values with a one-line
`ConfigError` naming the key, and `to_toml` prints the effective config.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from truav.errors import UserError
from truav.channel_catalog import ENVIRONMENTS, LINK_MODELS, MODELS, TR36777_HEIGHTS


UAV_STARTS = ("random", "persist", "center")
MOBILITIES = ("builtin", "sumo")


class ConfigError(UserError):
    """A user mistake in a config file or override: the message names the key."""


def param(default: Any, lo: float | None = None, hi: float | None = None):
    """A config field with an inclusive valid range checked on load."""
    return field(default=default, metadata={"range": (lo, hi)})


@dataclass(frozen=True)
class ScenarioConfig:
    """The environment block of the paper's Table."""

    area_m: float = param(5000.0, 100.0, 1e6)
    """Side of the square urban area (m). Paper: 5000 x 5000 m."""
    n_vehicles: int = param(200, 1, 100_000)
    """Ground vehicles. Paper: 200."""
    n_uavs: int = param(5, 1, 1024)
    """UAV relays, one learning agent each. Paper: 5."""
    uav_altitude_m: float = param(100.0, 1.0, 1000.0)
    """Fixed flight level (m). Paper: 100 m."""
    uav_speed_mps: float = param(15.0, 0.1, 100.0)
    """Maximum UAV horizontal speed (m/s); the paper sweeps 5-25 m/s."""
    comm_range_m: float = param(500.0, 1.0, 1e5)
    """UAV-to-vehicle link range (m), horizontal; defines coverage. Paper: 500 m."""
    step_s: float = param(1.0, 0.01, 60.0)
    """Duration of one simulation step (s). The paper: 100 steps = 100 s."""
    steps_per_episode: int = param(100, 1, 1_000_000)
    """Steps per episode. Paper: 100."""
    rsu_intersections: tuple[tuple[int, int], ...] = param(((4, 4), (16, 4), (4, 16), (16, 16)))
    """Grid indices (i, j) of the intersections with an RSU. The paper places
    its 4 RSUs "near the corners" and at "selected intersections and major
    corridors": here the major intersections nearest each corner."""
    rsu_height_m: float = param(10.0, 0.0, 200.0)
    """RSU antenna height (m); RSUs sit at the four corners (paper), on masts of
    typical roadside height (5-10 m; 3GPP TR 37.885 uses 5 m RSU antennas)."""
    uav_start: str = param("random")
    """Where UAVs start an episode: "random" (uniform over the area, a fresh
    deployment each episode, so agents learn to reposition from anywhere),
    "persist" (where the last episode ended: a swarm serving the city
    continuously; random at the very first reset) or "center". Random draws
    come from the world's generator."""
    mobility: str = param("builtin")
    """Where the vehicles' positions come from: "builtin" (the grid's own IDM
    car following, world/roads.py) or "sumo" (a trace SUMO recorded on a grid
    network like this one, replayed: `truav traffic build`, section [sumo];
    needs the optional `sumo` extra)."""


@dataclass(frozen=True)
class RoadConfig:
    """Grid road network and turning behaviour (the paper says only "regular
    grid of two-lane roads", "turning probabilities typical of urban areas" and
    "higher vehicle densities near major intersections")."""

    block_m: float = param(250.0, 50.0, 1e5)
    """Distance between parallel roads (m): 250 m, the block of the Manhattan
    grid of ETSI TR 101 112 (UMTS 30.03); 21 x 21 roads over 5 km."""
    p_straight: float = param(0.5, 0.0, 1.0)
    """Turning probabilities of the Manhattan mobility model (ETSI TR 101 112,
    UMTS 30.03): straight 0.5, left 0.25, right 0.25."""
    p_left: float = param(0.25, 0.0, 1.0)
    """Probability of turning left at an intersection (see p_straight)."""
    p_right: float = param(0.25, 0.0, 1.0)
    """Probability of turning right at an intersection (see p_straight)."""
    p_attract: float = param(0.8, 0.0, 1.0)
    """Probability that a driver, at an intersection, takes the turn that brings
    it closest to its home major intersection instead of a Manhattan draw.
    This gravity-style attraction (cf. the activity-based "hotspot" mobility of
    Kim et al., Infocom 2006) produces the clustering near major intersections
    that the paper describes. 0.8 makes it as strong as the paper's figures
    imply (~90% of vehicles within 500 m of five points); 0.6 is milder."""
    major_intersections: tuple[tuple[int, int], ...] = param(
        ((4, 4), (16, 4), (4, 16), (16, 16), (10, 10))
    )
    """Grid indices (i, j) of the city's major intersections (a fixed map):
    the four RSU sites near the corners and the city centre. Each vehicle has
    one as its home; traffic clusters around them."""
    hotspot_move_prob: float = param(0.0, 0.0, 1.0)
    """Probability that each traffic hotspot (the intersection a cluster of
    vehicles gathers at; at first the major intersections) moves at the start
    of an episode, by hotspot_step_blocks to a neighbouring intersection inside
    the box of the major intersections; its vehicles then head for the new
    site. 0 (default): fixed hotspots, the literal reading of "higher vehicle
    densities near major intersections". The paper's introduction speaks of
    spatio-temporal hotspot dynamics that fixed patrol paths cannot follow
    (`--preset paper`)."""
    hotspot_step_blocks: int = param(4, 1, 1000)
    """How far a hotspot moves at once, in blocks (4 x 250 m = 1 km: two
    comm ranges, so a moved cluster leaves the coverage of a UAV parked on it)."""
    turn_speed_mps: float = param(5.5, 0.5, 50.0)
    """Speed for turning and for crossing a major (signalised) intersection
    (~20 km/h, the usual urban turning speed in SUMO's junction model)."""
    warmup_steps: int = param(200, 0, 100_000)
    """Mobility-only steps run at the first reset so traffic starts clustered."""


@dataclass(frozen=True)
class IDMConfig:
    """Intelligent Driver Model constants (Treiber, Hennecke & Helbing 2000);
    city-traffic values of Treiber & Kesting, "Traffic Flow Dynamics", Tab. 11.2."""

    desired_speed_mps: float = param(15.0, 0.5, 60.0)
    """v0: desired speed, 54 km/h (urban limit 50-60 km/h)."""
    time_headway_s: float = param(1.0, 0.1, 5.0)
    """T: safe time headway (city traffic: 1.0 s)."""
    max_accel: float = param(1.0, 0.1, 10.0)
    """a: maximum acceleration (m/s^2)."""
    comfort_decel: float = param(1.5, 0.1, 10.0)
    """b: comfortable deceleration (m/s^2)."""
    min_gap_m: float = param(2.0, 0.0, 50.0)
    """s0: jam distance (m)."""
    exponent: float = param(4.0, 1.0, 10.0)
    """delta: acceleration exponent."""
    vehicle_length_m: float = param(5.0, 1.0, 30.0)
    """Vehicle length (m)."""


@dataclass(frozen=True)
class TrafficConfig:
    """Packets generated at vehicles for relaying to an RSU."""

    packet_rate_hz: float = param(0.2, 0.0, 1000.0)
    """Mean Poisson packet rate per vehicle (1/s): one report every 5 s, within
    the 1-10 s reporting intervals of floating-car-data collection."""
    packet_bytes: int = param(300, 1, 1_000_000)
    """Packet size (bytes): a typical CAM is 200-400 bytes (ETSI EN 302 637-2)."""
    queue_limit: int = param(20, 1, 100_000)
    """Per-vehicle queue bound (packets); arrivals beyond it are dropped."""
    deadline_steps: int = param(10, 1, 1000)
    """Packets not delivered within this many steps (10 s) expire, as in
    delay-tolerant vehicular data collection."""


@dataclass(frozen=True)
class ChannelConfig:
    """Air-to-ground and air-to-air links (paper: 20 MHz, noise 1e-9 W,
    vehicle 0.1 W, UAV 1.0 W; LoS model after Al-Hourani et al., IEEE WCL 2014).
    The model's formulas and sources: world/channel_models.py, docs/explanation/channel-models.md."""

    model: str = param("paper")
    """Channel model of the links: "paper" (the default, every number as before), "al-hourani",
    "3gpp-uma-av", "3gpp-umi-av" or "3gpp-rma-av" (TR 36.777 Annex B for UAV-RSU links);
    `truav config show` lists each one's formulas per link and its source."""
    environment: str = param("urban")
    """Al-Hourani's environment (his Table I: suburban, urban, dense-urban, highrise-urban) for the
    air-to-ground links of the models other than "paper", which takes los_a/los_b/eta_* instead."""
    carrier_hz: float = param(5.9e9, 1e8, 1e11)
    """Carrier frequency (Hz): 5.9 GHz, IEEE 802.11p (paper)."""
    bandwidth_hz: float = param(20e6, 1e3, 1e10)
    """Channel bandwidth (Hz). Paper: 20 MHz."""
    noise_w: float = param(1e-9, 1e-20, 1.0)
    """Noise power (W). Paper: 1e-9 W."""
    vehicle_tx_w: float = param(0.1, 1e-6, 100.0)
    """Vehicle transmit power (W). Paper: 0.1 W."""
    uav_tx_w: float = param(1.0, 1e-6, 100.0)
    """UAV transmit power to UAVs and RSUs (W). Paper: 1.0 W."""
    antenna_gain_dbi: float = param(0.0, -20.0, 40.0)
    """Sum of transmit and receive antenna gains (dBi); omni antennas."""
    los_a: float = param(9.61, 0.0, 100.0)
    """Al-Hourani 'a' for the urban environment (9.61)."""
    los_b: float = param(0.16, 0.0, 10.0)
    """Al-Hourani 'b' for the urban environment (0.16)."""
    eta_los_db: float = param(1.0, 0.0, 100.0)
    """Excess loss on LoS links (dB), urban: 1 dB."""
    eta_nlos_db: float = param(20.0, 0.0, 100.0)
    """Excess loss on NLoS links (dB), urban: 20 dB."""
    a2a_los_probability: float = param(1.0, 0.0, 1.0)
    """UAV-to-UAV LoS probability: both ends fly above the rooftops, so air-to-air
    links are modelled as LoS (Mozaffari et al., IEEE COMST 2019)."""


@dataclass(frozen=True)
class LinksConfig:
    """Who hears whose beacon: "ideal", every UAV every other's (the paper, and the default), or
    "channel": each beacon delivered or lost by the channel model's UAV-UAV link at the UAVs'
    distance through an 802.11p PHY abstraction, the same draws in the trainer and the swarm
    (world/link_phy.py, docs/explanation/channel-models.md "Beacon links")."""

    model: str = param("ideal")
    """Link model of the beacons: "ideal" or "channel"."""
    beacon_bytes: int = param(100, 1, 4095)
    """Size of a beacon frame on the air (bytes: MAC header, payload, FCS), for its error rate and airtime."""


@dataclass(frozen=True)
class EnergyConfig:
    """Mode-dependent UAV power profile (paper: hover 200 W, move 250 W)."""

    hover_w: float = param(200.0, 0.0, 1e5)
    """Power to stay aloft (W). Paper: 200 W."""
    move_w: float = param(250.0, 0.0, 1e5)
    """Power when cruising at move_ref_speed_mps (W). Paper: 250 W."""
    move_ref_speed_mps: float = param(25.0, 0.1, 100.0)
    """Speed at which move_w applies; propulsion above hover grows linearly with
    speed up to it (the paper: energy rises roughly linearly with speed)."""


@dataclass(frozen=True)
class LearnerConfig:
    """Tabular Q-learning (paper's RL block) plus the reward and state design."""

    learning_rate: float = param(0.1, 0.0, 1.0)
    """Q-learning step size. Paper: 0.1."""
    discount: float = param(0.95, 0.0, 1.0)
    """Discount factor. Paper: 0.95."""
    epsilon_start: float = param(1.0, 0.0, 1.0)
    """Initial exploration rate. Paper: 1.0."""
    epsilon_end: float = param(0.05, 0.0, 1.0)
    """Final exploration rate. Paper: 0.05."""
    epsilon_decay_fraction: float = param(0.8, 0.01, 1.0)
    """Exploration decays exponentially from start to end over this fraction
    of the episodes, then stays at epsilon_end."""
    episodes: int = param(5000, 1, 10_000_000)
    """Training episodes. Paper: 5000."""
    q_init_scale: float = param(0.01, 0.0, 10.0)
    """Q-tables start uniform in [0, q_init_scale) ("small random values")."""
    geofence: bool = param(False)
    """Never pick an action whose full move would leave the area (agents/qlearning.py). The paper is
    silent; off keeps the literal preset's results as they were, the `paper` preset turns it on
    (a greedy UAV pushing into a wall or corner keeps its state and stays there)."""
    w_relay: float = param(1.0, -100.0, 100.0)
    """alpha, weight of the relay term. Paper: 1.0."""
    w_coverage: float = param(0.25, -100.0, 100.0)
    """beta, weight of the coverage term. Paper: 0.25."""
    w_energy: float = param(0.15, -100.0, 100.0)
    """gamma, weight of the energy penalty. Paper: 0.15."""
    w_overlap: float = param(0.20, -100.0, 100.0)
    """delta, weight of the overlap penalty. Paper: 0.20."""
    grid_cells: int = param(10, 1, 50)
    """Cells per side of the state's spatial grid (10 -> 500 m cells). At most 50 (100 m cells on the
    paper's area, 44 MiB per Q-table with the other factors at their defaults): 1000 made every table
    8.6 GiB. The tables' memory as a whole is checked too (agents.state.check_qtable_memory)."""
    density_edges: tuple[float, ...] = param((1.0, 5.0, 15.0))
    """Vehicles in range: level = number of edges <= count."""
    queue_edges: tuple[float, ...] = param((1.0, 10.0, 30.0))
    """Packets queued at connected vehicles: level edges."""
    neighbour_edges_m: tuple[float, ...] = param((1000.0, 2000.0))
    """Nearest neighbour UAV distance (m): < 2R overlaps, < 4R near, else far."""
    rsu_edges_m: tuple[float, ...] = param((1000.0, 2500.0))
    """Nearest RSU distance (m): level edges."""
    neighbour_sectors: int = param(0, 0, 16)
    """Direction of the nearest heard neighbour UAV in this many equal sectors
    (counter-clockwise from east) as a further state factor, beside its
    distance level; 0 (the default) keeps distance only. The paper's state
    has "relative positions of neighbouring UAVs"; a direction tells an agent
    which way to move away from an overlap."""
    sense_range_m: float = param(0.0, 0.0, 1e5)
    """What a UAV senses of denser areas nearby: the vehicles it hears (their
    CAM position beacons) beyond its comm range and within this radius (m)
    are counted per direction sector, and the state gets the sector holding
    the most of them (or "none sensed") as a further factor. 0 (the default)
    turns sensing off; must exceed scenario.comm_range_m when on. The world
    computes it (world/network.py, DENSEST), as it does vehicles in range."""
    sense_sectors: int = param(4, 1, 16)
    """Direction sectors of the sensing above, equal, counter-clockwise from
    east, the first starting at east (4: the quadrants east to north, north to
    west, west to south, south to east); the factor has sense_sectors + 1
    levels (an agent's view: densest_sector, docs/reference/agent-api.md)."""
    sense_disc: bool = param(False)
    """With sensing on, also sense where the densest disc is: among the vehicles
    within sense_range_m, the one with the most vehicles within comm range of
    it, its offset from the UAV and that count (an agent's view: disc_offset,
    disc_vehicles; world/network.py, DISC_DX). Off (the default) they stay 0
    and the world skips the count, which about triples its step under
    --preset paper (25 -> 80 us per environment-step, measured); agents
    trained on it (ppo-disc) fly with it on."""
    w_difference: float = param(0.0, -100.0, 100.0)
    """Weight of the difference reward's coverage term: the vehicles in the
    UAV's range that no other UAV covers (world.network.EXCLUSIVE, what the
    swarm's coverage would lose without this UAV: G(z) - G(z without i) for
    coverage), over the fair share n_vehicles / n_uavs. 0 (the default) leaves
    the paper's reward; the difference design sets it (e.g. 0.25) with
    w_coverage and w_overlap at 0, replacing the local coverage term and the
    overlap penalty that approximates what it subtracts (agents/reward.py)."""
    w_shaping: float = param(0.0, -100.0, 100.0)
    """Potential-based shaping (Ng, Harada & Russell 1999): the reward gets
    F = discount phi(s') - phi(s), phi = w_shaping x vehicles in range / the
    fair share, which leaves the optimal policy unchanged and pays a move
    towards denser traffic at once. 0 (the default): no shaping."""
    predict_sectors: int = param(0, 0, 16)
    """Prediction: each UAV keeps a decayed map of the vehicle density it has
    seen (predict_cells x predict_cells cells; each observation multiplies it
    by predict_decay and adds the vehicles in range to the UAV's cell), and
    the state gets the direction, in this many sectors, of the map's densest
    cell where it expects traffic (or "here / nothing seen yet"): a factor of
    predict_sectors + 1 levels. 0 (the default): off (agents/prediction.py)."""
    predict_cells: int = param(10, 1, 100)
    """Cells per side of the prediction map (10: 500 m cells, one comm range)."""
    predict_decay: float = param(0.99, 0.0, 1.0)
    """Per-observation decay of the prediction map (0.99: a half-life of 69
    steps, about the 200 s a hotspot dwells under `--preset paper`)."""


PATROL_ASSIGNMENTS = ("nearest", "fixed")


@dataclass(frozen=True)
class PatrolConfig:
    """Trajectory-knowledge baseline (after Zhou et al.): pre-planned circular
    patrols centred on the major intersections (roads.major_intersections),
    routing from advance knowledge of the planned positions."""

    radius_m: float = param(250.0, 0.0, 1e5)
    """Orbit radius (m) around the patrolled intersection: half the comm range,
    so the intersection (where traffic clusters) stays in range all the orbit
    while the swept disc reaches 1.5 x the range."""
    speed_fraction: float = param(1.0, 0.0, 1.0)
    """Cruise speed as a fraction of scenario.uav_speed_mps, for the transit to
    the orbit and the orbit itself (1.0: the swept speed, like the learners'
    full-speed actions)."""
    assignment: str = param("nearest")
    """How the plan, made at deployment, gives orbits to UAVs: "nearest"
    (greedy minimum-transit matching of start positions to orbit entry points)
    or "fixed" (UAV k flies orbit k mod the number of sites, whatever its start).
    With more UAVs than sites, the extra UAVs share an orbit, evenly phased."""


@dataclass(frozen=True)
class CentralConfig:
    """Centralized baseline (after Chen et al.): a controller behind the RSUs
    runs a multi-agent soft actor-critic on the joint state. Its control plane
    is explicit: every UAV uploads its state each step over the same 5.9 GHz
    radio (along the min-time UAV/RSU route), the controller computes the
    joint action, and a command comes back; the round trip delays the action,
    and the airtime is taken from packet service and charged as radio energy.
    The network parameters are literature values, not fitted to the paper."""

    upload_bytes: int = param(200, 1, 1_000_000)
    """State report each UAV uploads per step (bytes): a CAM-sized status
    message (ETSI EN 302 637-2: 200-400 bytes) carrying position, velocity
    and the UAV's local traffic features."""
    download_bytes: int = param(78, 1, 1_000_000)
    """Command the controller sends each UAV per step (bytes): a MAVLink 2
    SET_POSITION_TARGET_LOCAL_NED (53-byte payload + 12-byte header +
    13-byte signature)."""
    update_period_steps: int = param(1, 1, 1_000_000)
    """Steps between control rounds (1: upload and command every step). Between
    rounds UAVs keep their last commanded action."""
    backhaul_latency_s: float = param(0.005, 0.0, 10.0)
    """One-way latency RSU <-> controller over the wired backhaul (s): a few ms
    for an edge site in the metro network (ETSI MEC; 5G URLLC budgets 1-10 ms)."""
    compute_latency_s: float = param(0.005, 0.0, 10.0)
    """Controller time to batch the states and run the joint policy (s)."""
    hidden: int = param(64, 4, 4096)
    """Width of the two hidden layers of the actor and of each critic: small
    MLPs, as the joint state is only U x 8 numbers (and the CPU budget of the
    10-seed x 5-speed sweep is tight; see docs/results/reproduction.md)."""
    actor_lr: float = param(3e-4, 0.0, 1.0)
    """Adam step size of the actor (Haarnoja et al. 2018; CleanRL's discrete SAC)."""
    critic_lr: float = param(3e-4, 0.0, 1.0)
    """Adam step size of the twin critics and of the temperature."""
    batch_size: int = param(64, 1, 1_000_000)
    """Transitions per gradient step, per seed (CleanRL's discrete SAC: 64)."""
    buffer_size: int = param(100_000, 1, 100_000_000)
    """Replay capacity per seed (transitions)."""
    update_every: int = param(4, 1, 1_000_000)
    """Environment steps per gradient step (CleanRL's discrete SAC: 4)."""
    learning_starts: int = param(5_000, 0, 100_000_000)
    """Environment steps of uniformly random actions before learning starts."""
    tau: float = param(0.005, 0.0, 1.0)
    """Polyak rate of the target critics (Haarnoja et al. 2018)."""
    init_alpha: float = param(1.0, 1e-6, 100.0)
    """Initial temperature alpha (then tuned to the target entropy)."""
    target_entropy_scale: float = param(0.89, 0.0, 1.0)
    """Target entropy per UAV = this x log(16), the temperature being tuned to
    it (discrete SAC, Christodoulou 2019; 0.89 is CleanRL's default)."""
    geofence: bool = param(False)
    """The UAVs' autopilot refuses a commanded move that would leave the area
    and flies the next allowed action instead (cyclically, as TRUAV's
    learner.geofence does with its exploratory draws); the SAC learns from the
    action it commanded, the fence being part of its environment. Off keeps
    the literal preset's numbers; the `paper` preset turns it on (without it a
    persistent swarm under the SAC ends pinned to the borders: 2.8% coverage,
    docs/results/reproduction.md)."""
    evaluate_sampled: bool = param(False)
    """Evaluation (and a swarm run from a trained policy) samples each action
    from the actor's distribution pi instead of taking its mode. False (the
    default, as for TRUAV's greedy evaluation) keeps every number; True is the
    protocol of a maximum-entropy learner's stochastic policy, whose training
    coverage can exceed its mode's (docs/results/reproduction.md, "A fair centralized
    baseline"). Draws come from each seed's SAC generator."""
    reward_scale: float = param(1.0, 1e-6, 1e6)
    """Factor on the reward the SAC learns from (stored in its replay); the
    reported reward is unscaled. SAC is sensitive to reward scale against its
    temperature (Haarnoja et al. 2018, Sec. 5.2); a tuning knob
    (docs/results/reproduction.md, "A fair centralized baseline")."""


@dataclass(frozen=True)
class SumoConfig:
    """SUMO traffic (scenario.mobility = "sumo"): a netgenerate grid of the
    scenario's size and block length, trips drawn by SUMO's randomTrips.py
    towards the major intersections, driven by SUMO's own car following and
    junction model; vehicle positions recorded once per step into a trace."""

    lanes_per_direction: int = param(1, 1, 8)
    """Lanes of each road per direction (the paper's "two-lane roads": one each way)."""
    trace_episodes: int = param(20, 1, 100_000)
    """Episodes of traffic the trace holds; episode e of an environment replays
    window (offset + e) mod trace_episodes, the offset drawn from its generator."""
    warmup_s: float = param(300.0, 0.0, 100_000.0)
    """SUMO time run before recording starts, so every vehicle is inserted and
    traffic has gathered at the hotspots."""
    hotspot_weight: float = param(20.0, 0.0, 1e6)
    """Extra weight of a trip destination at a major intersection against one
    far from all (randomTrips.py's edge weights: 1 + hotspot_weight x
    exp(-(d / hotspot_radius_m)^2), d the distance to the nearest major intersection)."""
    hotspot_radius_m: float = param(500.0, 1.0, 1e6)
    """Radius of the hotspots' pull (m): one comm range."""
    signals_at_major: bool = param(True)
    """Traffic lights at the major intersections (netgenerate --tls.set); the others are priority junctions."""
    trace_seed: int = param(0, 0, 2**31 - 1)
    """Seed of netgenerate, randomTrips.py and SUMO: one trace per scenario and trace_seed."""


@dataclass(frozen=True)
class FederatedConfig:
    """Federated TRUAV (the paper's future work: UAVs that "periodically
    share distilled policy information"): every `every` episodes each UAV
    shares the Q rows of the states it visited since its last share, with its
    visit counts, and merges its peers' rows by visit-weighted averaging
    (agents/federated.py), bounded so a peer's table can move an entry only so
    far. Who hears whom: all-to-all (every UAV's share reaches every other
    UAV, as the lock-step beacons do)."""

    every: int = param(0, 0, 1_000_000)
    """Episodes between shares (0: off, independent learners as in the paper).
    A share happens after episode e when (e + 1) % every == 0."""
    max_weight: float = param(0.5, 0.0, 1.0)
    """Largest fraction of the way from its own value to a peer's value that
    one peer's row may move an entry in one merge (the visit-weighted
    average's weight of that peer is capped at this): a hostile or confused
    peer claiming huge counts moves a table at most this far."""
    max_rows: int = param(960, 1, 1_000_000)
    """Rows a UAV shares at most per share: the most visited of the states it
    visited since its last share (ties: lower state first); the bus splits
    them over messages of at most truav.wire.schema_names.MAX_QSHARE_ROWS rows."""
    q_bound: float = param(1e4, 0.0, 1e12)
    """A share holding a Q value of magnitude above this (or NaN, inf) is
    refused whole: no reward of the scenario's reward design comes near it
    (per-step rewards are O(1) and discount < 1 bounds Q by r_max / (1 - discount))."""


@dataclass(frozen=True)
class Config:
    """The whole effective configuration of a run."""

    scenario: ScenarioConfig = field(default_factory=ScenarioConfig)
    roads: RoadConfig = field(default_factory=RoadConfig)
    idm: IDMConfig = field(default_factory=IDMConfig)
    traffic: TrafficConfig = field(default_factory=TrafficConfig)
    channel: ChannelConfig = field(default_factory=ChannelConfig)
    links: LinksConfig = field(default_factory=LinksConfig)
    energy: EnergyConfig = field(default_factory=EnergyConfig)
    learner: LearnerConfig = field(default_factory=LearnerConfig)
    patrol: PatrolConfig = field(default_factory=PatrolConfig)
    central: CentralConfig = field(default_factory=CentralConfig)
    sumo: SumoConfig = field(default_factory=SumoConfig)
    federated: FederatedConfig = field(default_factory=FederatedConfig)

    def replace(self, **sections: Mapping[str, Any]) -> "Config":
        """A copy with some keys changed, validated: replace(scenario={"n_uavs": 3})."""
        data = to_dict(self)
        for name, values in sections.items():
            data[name] = {**data.get(name, {}), **values}
        return config_from_dict(data)


def to_dict(cfg: Config) -> dict[str, dict[str, Any]]:
    """Plain nested dict of the config (tuples kept)."""
    return {f.name: dataclasses.asdict(getattr(cfg, f.name)) for f in dataclasses.fields(cfg)}


def _coerce(section: str, f: dataclasses.Field, value: Any) -> Any:
    key = f"{section}.{f.name}"
    default = f.default
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigError(f"{key}: expected true/false, got {value!r}")
        return value
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{key}: expected an integer, got {value!r}")
    elif isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{key}: expected a number, got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise ConfigError(f"{key}: must be finite, got {value!r}")
    elif isinstance(default, str):
        if not isinstance(value, str):
            raise ConfigError(f"{key}: expected a string, got {value!r}")
    elif isinstance(default, tuple):
        value = _coerce_tuple(key, default, value)
    lo, hi = f.metadata.get("range", (None, None))
    if lo is not None and value < lo or hi is not None and value > hi:
        raise ConfigError(f"{key}: {value!r} is outside [{lo}, {hi}]")
    return value


def _coerce_tuple(key: str, default: tuple, value: Any) -> tuple:
    if not isinstance(value, (list, tuple)) or len(value) == 0:
        raise ConfigError(f"{key}: expected a non-empty list, got {value!r}")
    if default and isinstance(default[0], tuple):  # list of integer pairs
        pairs = []
        for item in value:
            if (not isinstance(item, (list, tuple)) or len(item) != 2
                    or not all(isinstance(v, int) and not isinstance(v, bool) for v in item)):
                raise ConfigError(f"{key}: expected a list of [i, j] integer pairs, got {item!r}")
            pairs.append((int(item[0]), int(item[1])))
        return tuple(pairs)
    numbers = []
    for item in value:
        if isinstance(item, bool) or not isinstance(item, (int, float)) or not math.isfinite(item):
            raise ConfigError(f"{key}: expected finite numbers, got {item!r}")
        numbers.append(float(item))
    if any(b <= a for a, b in zip(numbers, numbers[1:])):
        raise ConfigError(f"{key}: bin edges must increase strictly, got {numbers}")
    return tuple(numbers)


def config_from_dict(data: Mapping[str, Any]) -> Config:
    """Build and validate a Config from nested mappings; missing keys keep defaults."""
    sections = {}
    for sec in dataclasses.fields(Config):
        sections[sec.name] = sec.default_factory  # type: ignore[misc]
    unknown = set(data) - set(sections)
    if unknown:
        raise ConfigError(f"unknown section '{sorted(unknown)[0]}' (known: {', '.join(sections)})")
    built = {}
    for name, factory in sections.items():
        values = data.get(name, {})
        if not isinstance(values, Mapping):
            raise ConfigError(f"section '{name}' must be a table")
        cls = type(factory())
        fields = {f.name: f for f in dataclasses.fields(cls)}
        bad = set(values) - set(fields)
        if bad:
            close = difflib.get_close_matches(sorted(bad)[0], list(fields), n=1)
            hint = f"did you mean '{name}.{close[0]}'?" if close else f"known: {', '.join(fields)}"
            raise ConfigError(f"unknown key '{name}.{sorted(bad)[0]}' ({hint})")
        built[name] = cls(**{k: _coerce(name, fields[k], v) for k, v in values.items()})
    cfg = Config(**built)
    _check_consistency(cfg)
    return cfg


def _check_consistency(cfg: Config) -> None:
    r, s = cfg.roads, cfg.scenario
    if abs(r.p_straight + r.p_left + r.p_right - 1.0) > 1e-9:
        raise ConfigError("roads.p_straight + p_left + p_right must sum to 1")
    if 0.0 < cfg.learner.sense_range_m <= s.comm_range_m:
        raise ConfigError(f"learner.sense_range_m: {cfg.learner.sense_range_m:g} must be 0 (off) or exceed "
                          f"scenario.comm_range_m ({s.comm_range_m:g})")
    if s.mobility not in MOBILITIES:
        raise ConfigError(f"scenario.mobility: {s.mobility!r} is not one of {', '.join(MOBILITIES)}")
    if s.uav_start not in UAV_STARTS:
        raise ConfigError(f"scenario.uav_start: {s.uav_start!r} is not one of {', '.join(UAV_STARTS)}")
    n_roads = n_grid_roads(cfg)
    if n_roads < 2:
        raise ConfigError("roads.block_m: the area must hold at least two roads per axis")
    for key, sites in (("roads.major_intersections", r.major_intersections),
                       ("scenario.rsu_intersections", s.rsu_intersections)):
        for i, j in sites:
            if not (0 <= i < n_roads and 0 <= j < n_roads):
                raise ConfigError(f"{key}: ({i}, {j}) is outside the {n_roads}x{n_roads} grid")
    if s.mobility == "builtin" and s.n_vehicles > grid_vehicle_capacity(cfg):
        raise ConfigError(f"scenario.n_vehicles: {s.n_vehicles} vehicles do not fit on the road grid of "
                          f"scenario.area_m {s.area_m:g} and roads.block_m {r.block_m:g} (at most "
                          f"{grid_vehicle_capacity(cfg)}, one per {VEHICLE_SLOT_M:g} m of lane)")
    if cfg.idm.desired_speed_mps * s.step_s >= r.block_m:
        raise ConfigError("idm.desired_speed_mps: a vehicle must not cross a whole block in one step")
    if cfg.patrol.assignment not in PATROL_ASSIGNMENTS:
        raise ConfigError(f"patrol.assignment: {cfg.patrol.assignment!r} is not one of {', '.join(PATROL_ASSIGNMENTS)}")
    if cfg.learner.epsilon_end > cfg.learner.epsilon_start:
        raise ConfigError("learner.epsilon_end must not exceed learner.epsilon_start")
    _check_channel(cfg)


PAPER_CHANNEL_KEYS = ("los_a", "los_b", "eta_los_db", "eta_nlos_db", "a2a_los_probability")
"""Keys of the paper's channel model only; the other models take channel.environment instead."""


def _check_channel(cfg: Config) -> None:
    ch, default = cfg.channel, ChannelConfig()
    if cfg.links.model not in LINK_MODELS:
        raise ConfigError(f"links.model: {cfg.links.model!r} is not one of {', '.join(LINK_MODELS)}")
    if ch.model not in MODELS:
        raise ConfigError(f"channel.model: {ch.model!r} is not one of {', '.join(MODELS)}")
    if ch.environment not in ENVIRONMENTS:
        raise ConfigError(f"channel.environment: {ch.environment!r} is not one of {', '.join(ENVIRONMENTS)}")
    if ch.model == "paper" and ch.environment != default.environment:
        raise ConfigError(f"channel.environment: applies to the models other than 'paper', which takes "
                          f"channel.{'/'.join(PAPER_CHANNEL_KEYS[:2])}/eta_* instead; set channel.model too")
    if ch.model != "paper":
        for key in PAPER_CHANNEL_KEYS:
            if getattr(ch, key) != getattr(default, key):
                raise ConfigError(f"channel.{key}: belongs to channel.model 'paper', not {ch.model!r} "
                                  "(which takes channel.environment)")
    if ch.model in TR36777_HEIGHTS:
        lo, hi = TR36777_HEIGHTS[ch.model]
        if not lo < cfg.scenario.uav_altitude_m <= hi:
            raise ConfigError(f"scenario.uav_altitude_m: {cfg.scenario.uav_altitude_m:g} m is outside ({lo:g}, {hi:g}] m, "
                              f"where TR 36.777's aerial formulas of channel.model {ch.model!r} hold")


def n_grid_roads(cfg: Config) -> int:
    """Roads per axis: one every block_m, including both borders."""
    return int(math.floor(cfg.scenario.area_m / cfg.roads.block_m + 1e-9)) + 1


VEHICLE_SLOT_M = 25.0
"""The built-in mobility spawns each vehicle on its own slot of this much lane."""


def grid_vehicle_capacity(cfg: Config) -> int:
    """Vehicles the built-in road grid can spawn: one per slot of its 4 lanes per road."""
    n_roads = n_grid_roads(cfg)
    return 4 * n_roads * int((n_roads - 1) * cfg.roads.block_m // VEHICLE_SLOT_M)


def read_toml(path: str | Path, what: str, error: type[Exception]) -> dict[str, Any]:
    """A TOML file as a dict; a missing or malformed file raises ``error`` with a one-line reason."""
    p = Path(path)
    if not p.exists():
        raise error(f"{what} not found: {p}")
    if not p.is_file():
        raise error(f"{what} {p}: not a regular file")
    try:
        text = p.read_bytes().decode("utf-8")
    except OSError as exc:
        raise error(f"{what} {p}: cannot read it ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise error(f"{what} {p}: not a text file (not UTF-8), so not TOML") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{what} {p}: not valid TOML ({exc})") from None
    except RecursionError:  # tomllib recurses per level of nested arrays and inline tables
        raise error(f"{what} {p}: nested too deeply to be a config (not valid here)") from None


def load_config(path: str | Path | None = None, overrides: Mapping[str, Any] | None = None,
                base: Mapping[str, Mapping[str, Any]] | None = None) -> Config:
    """Defaults, then ``base`` (e.g. the --quick settings), then a TOML file, then overrides
    ({"scenario": {...}}): whatever the user wrote explicitly wins."""
    data: dict[str, Any] = {name: dict(values) for name, values in (base or {}).items()}
    layers = [read_toml(path, "config file", ConfigError) if path is not None else {}, overrides or {}]
    for layer in layers:
        for name, values in layer.items():
            if isinstance(values, Mapping) and isinstance(data.get(name), Mapping):
                data[name] = {**data[name], **values}
            else:
                data[name] = dict(values) if isinstance(values, Mapping) else values
    return config_from_dict(data)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return repr(v)


def to_toml(cfg: Config) -> str:
    """The effective config as TOML that load_config reads back unchanged."""
    lines = []
    for name, values in to_dict(cfg).items():
        lines.append(f"[{name}]")
        lines.extend(f"{k} = {_toml_value(v)}" for k, v in values.items())
        lines.append("")
    return "\n".join(lines)

"""The channel models a config may name (channel.model, channel.environment): their names, which formula
each link uses, their sources and published parameters. Base layer (no numpy): the config checks names
and bounds against it; the formulas are in world/channel_models.py."""

from __future__ import annotations

from typing import NamedTuple


class Model(NamedTuple):
    uplink: str
    backhaul: str
    relay: str
    source: str


AL_HOURANI_2014 = ("A. Al-Hourani, S. Kandeepan, S. Lardner, Optimal LAP Altitude for Maximum Coverage, "
                   "IEEE WCL 3(6), 2014, Eq. 5 and Table I")
TR36777 = "3GPP TR 36.777 V15.0.0 (2017-12), Annex B, Tables B-1 and B-2"

MODELS: dict[str, Model] = {
    "paper": Model("paper two-state", "paper two-state", "paper two-state (a2a_los_probability)",
                   "the paper's Sec. System model as read by this project: Al-Hourani LoS probability with "
                   "channel.los_a/los_b/eta_*, ergodic two-state Shannon rate"),
    "al-hourani": Model("Al-Hourani", "Al-Hourani", "free space", AL_HOURANI_2014),
    "3gpp-uma-av": Model("Al-Hourani", "TR 36.777 UMa-AV", "free space", TR36777 + "; vehicle-UAV: Al-Hourani et al. 2014"),
    "3gpp-umi-av": Model("Al-Hourani", "TR 36.777 UMi-AV", "free space", TR36777 + "; vehicle-UAV: Al-Hourani et al. 2014"),
    "3gpp-rma-av": Model("Al-Hourani", "TR 36.777 RMa-AV", "free space", TR36777 + "; vehicle-UAV: Al-Hourani et al. 2014"),
}
"""channel.model: which formula each link uses, and where it comes from."""

ENVIRONMENTS: dict[str, tuple[float, float, float, float]] = {
    "suburban": (4.88, 0.43, 0.1, 21.0),
    "urban": (9.61, 0.16, 1.0, 20.0),
    "dense-urban": (12.08, 0.11, 1.6, 23.0),
    "highrise-urban": (27.23, 0.08, 2.3, 34.0),
}
"""Al-Hourani et al. 2014, Table I: (a, b, eta_LoS dB, eta_NLoS dB) per environment."""

TR36777_HEIGHTS: dict[str, tuple[float, float]] = {
    "3gpp-uma-av": (22.5, 300.0), "3gpp-umi-av": (22.5, 300.0), "3gpp-rma-av": (10.0, 300.0),
}
"""Aerial-UE heights (lo exclusive, hi inclusive, m) where Annex B's aerial formulas apply."""


LINK_MODELS: dict[str, str] = {
    "ideal": "every UAV hears every other's beacon (the paper)",
    "channel": "each beacon delivered or lost by channel.model's UAV-UAV path loss, SNR with channel.noise_w and "
               "the packet error rate of 802.11p 6 Mbit/s QPSK 1/2 (ns-3's NIST OFDM error model), counter-based "
               "seeded draws shared by the trainer and the swarm; world/link_phy.py",
}
"""links.model: who hears whose beacon."""


def describe() -> str:
    """TOML comment lines listing the models (`truav config show`)."""
    lines = ["# channel.model choices (world/channel_models.py, docs/explanation/channel-models.md):"]
    for name, m in MODELS.items():
        lines.append(f"#   {name}: vehicle-UAV {m.uplink}; UAV-RSU {m.backhaul}; UAV-UAV {m.relay}. Source: {m.source}")
    envs = ", ".join(f"{k} {v}" for k, v in ENVIRONMENTS.items())
    lines.append(f"# channel.environment (a, b, eta_LoS dB, eta_NLoS dB): {envs}")
    lines += ["# links.model choices:"] + [f"#   {name}: {text}" for name, text in LINK_MODELS.items()]
    return "\n".join(lines) + "\n\n"

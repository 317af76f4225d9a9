"""Beacon delivery of the `channel` link model against an ns-3 two-node simulation (docs/explanation/channel-models.md,
"Checked against ns-3").

    /tmp/v-ns3/bin/python docs/scripts/ns3_link_check.py --out docs/figures/ns3-link-check \
        [--models paper,3gpp-uma-av] [--set channel.noise_w=1e-10 ...] [--packets 2000] [--step 2]

Needs the optional ns-3 Python wheel (`pip install ns3==3.44.post0`, GPL-2.0, not a TRUAV dependency) with numpy,
numba and matplotlib next to it; run from the repository root (or with PYTHONPATH on it). Nothing of TRUAV imports
ns-3: this script only compares.

For each channel model, ns-3 is set up as world/link_phy.py assumes: two nodes at the same altitude, IEEE 802.11p
10 MHz at OfdmRate6MbpsBW10MHz, YansWifiPhy with NistErrorRateModel, Friis loss at channel.carrier_hz, tx power
channel.uav_tx_w in dBm with the antenna gain as TxGain (link_phy counts the gain once), RxNoiseFigure such that
ns-3's noise k T B NF (T = 290 K, B = 10 MHz) equals channel.noise_w. The paper model's air-to-air excess loss is
a tx power offset of -eta_LoS (and -eta_NLoS for the NLoS state, mixed with a2a_los_probability as link_phy mixes
successes). Beacons are broadcast (no acknowledgement, no retry) through a PacketSocket: the 802.11 PSDU is the
payload + LLC/SNAP 8 + MAC header 24 + FCS 4 bytes, so the payload is links.beacon_bytes - 36 and the PSDU has
link_phy's beacon size. One node broadcasts N beacons (1 ms apart) per distance; the receiver moves between
windows. Delivery ratio with a Wilson 95 % interval, against link_phy.delivery_probability at the same distance;
the airtime ns-3 gives the frame (tx start to rx end, traced) against link_phy.airtime_s. Finally, the cost of a
lock-step round trip (positions in, one beacon per UAV simulated, counts out) with --uavs nodes.

Writes <out>.csv and <out>.png; prints the max |difference|, the 50 % distances and the runtimes.
"""

from __future__ import annotations

import argparse
import ast
import csv
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from truav.config import load_config  # noqa: E402
from world import link_phy  # noqa: E402

BOLTZMANN_NS3 = 1.3803e-23  # the constant ns-3's InterferenceHelper uses, at 290 K
WIDTH_HZ = 10e6
ALTITUDE_M = 100.0
INTERVAL_US = 1000
TICK_US = 10000  # lock-step cost: a window long enough for one contended beacon from each of ~10 UAVs
MODE = "OfdmRate6MbpsBW10MHz"
PSDU_OVERHEAD_BYTES = 8 + 24 + 4  # LLC/SNAP, 802.11 data header (non-QoS), FCS
Z95 = 1.959964


def parse_sets(pairs: list[str]) -> dict[str, dict[str, object]]:
    """KEY=VALUE with KEY section.field; VALUE a Python literal, else a string."""
    out: dict[str, dict[str, object]] = {}
    for pair in pairs:
        key, _, raw = pair.partition("=")
        section, _, field = key.strip().partition(".")
        if not field or not _:
            raise SystemExit(f"--set {pair!r}: expected section.field=value")
        try:
            value = ast.literal_eval(raw)
        except (ValueError, SyntaxError):
            value = raw
        out.setdefault(section, {})[field] = value
    return out


def wilson(k: int, n: int) -> tuple[float, float]:
    p = k / n
    den = 1 + Z95 ** 2 / n
    mid = (p + Z95 ** 2 / (2 * n)) / den
    half = Z95 * math.sqrt(p * (1 - p) / n + Z95 ** 2 / (4 * n * n)) / den
    return max(0.0, mid - half), min(1.0, mid + half)


def crossing(d: np.ndarray, p: np.ndarray, level: float = 0.5) -> float:
    """First distance where p falls below level, linearly interpolated between samples."""
    below = np.flatnonzero(p < level)
    if not below.size or below[0] == 0:
        return math.nan
    i = below[0]
    return float(d[i - 1] + (p[i - 1] - level) / (p[i - 1] - p[i]) * (d[i] - d[i - 1]))


class Ns3:
    """The imported ns-3 module and a C++ helper for the airtime trace."""

    def __init__(self):
        t = time.perf_counter()
        from ns import ns  # noqa: PLC0415 (optional, slow: imported here only)
        import cppyy  # noqa: PLC0415

        self.import_s = time.perf_counter() - t
        self.ns, self.cppyy = ns, cppyy
        cppyy.cppdef("""
        #include "ns3/simulator.h"
        #include "ns3/packet.h"
        #include "ns3/config.h"
        #include "ns3/callback.h"
        namespace truav_ns3_check {
          double tx_start = -1, delay_sum = 0; long n_delay = 0;
          void TxBegin(ns3::Ptr<const ns3::Packet>, double) { tx_start = ns3::Simulator::Now().GetSeconds(); }
          void RxEnd(ns3::Ptr<const ns3::Packet>) {
            if (tx_start >= 0) { delay_sum += ns3::Simulator::Now().GetSeconds() - tx_start; n_delay++; } }
          void Connect() {
            ns3::Config::ConnectWithoutContext("/NodeList/0/DeviceList/0/$ns3::WifiNetDevice/Phy/PhyTxBegin",
                                               ns3::MakeCallback(&TxBegin));
            ns3::Config::ConnectWithoutContext("/NodeList/1/DeviceList/0/$ns3::WifiNetDevice/Phy/PhyRxEnd",
                                               ns3::MakeCallback(&RxEnd));
          }
          void Reset() { tx_start = -1; delay_sum = 0; n_delay = 0; }
        }
        """)
        self.probe = cppyy.gbl.truav_ns3_check

    def network(self, n_nodes: int, tx_dbm: float, gain_db: float, noise_figure_db: float, carrier_hz: float,
                payload: int, interval_us: int, preamble_detection: bool = True):
        """n_nodes at ALTITUDE_M, node i broadcasting `payload`-byte beacons every interval_us (node 0 only when
        n_nodes == 2); returns (mobility models, packet sinks)."""
        ns = self.ns
        nodes = ns.NodeContainer()
        nodes.Create(n_nodes)
        mob = ns.MobilityHelper()
        mob.SetMobilityModel("ns3::ConstantPositionMobilityModel")
        mob.Install(nodes)
        mobs = [nodes.Get(i).GetObject[ns.MobilityModel]() for i in range(n_nodes)]
        for i, m in enumerate(mobs):
            m.SetPosition(ns.Vector(10.0 * i, 0.0, ALTITUDE_M))
        channel = ns.YansWifiChannelHelper()
        channel.SetPropagationDelay("ns3::ConstantSpeedPropagationDelayModel")
        channel.AddPropagationLoss("ns3::FriisPropagationLossModel", "Frequency", ns.DoubleValue(carrier_hz))
        phy = ns.YansWifiPhyHelper()
        phy.SetChannel(channel.Create())
        phy.SetErrorRateModel("ns3::NistErrorRateModel")
        phy.Set("TxPowerStart", ns.DoubleValue(tx_dbm))
        phy.Set("TxPowerEnd", ns.DoubleValue(tx_dbm))
        phy.Set("TxGain", ns.DoubleValue(gain_db))
        phy.Set("RxGain", ns.DoubleValue(0.0))
        phy.Set("RxNoiseFigure", ns.DoubleValue(noise_figure_db))
        if not preamble_detection:
            phy.DisablePreambleDetectionModel()
        wifi = ns.WifiHelper()
        wifi.SetStandard(ns.WIFI_STANDARD_80211p)
        wifi.SetRemoteStationManager("ns3::ConstantRateWifiManager", "DataMode", ns.StringValue(MODE),
                                     "NonUnicastMode", ns.StringValue(MODE))
        mac = ns.WifiMacHelper()
        mac.SetType("ns3::AdhocWifiMac")
        devs = wifi.Install(phy, mac, nodes)
        ns.PacketSocketHelper().Install(nodes)
        senders = [0] if n_nodes == 2 else range(n_nodes)
        for i in senders:
            remote = ns.PacketSocketAddress()
            remote.SetSingleDevice(devs.Get(i).GetIfIndex())
            remote.SetPhysicalAddress(ns.Mac48Address.GetBroadcast().ConvertTo())
            remote.SetProtocol(1)
            client = ns.CreateObject[ns.PacketSocketClient]()
            client.SetRemote(remote)
            client.SetAttribute("PacketSize", ns.UintegerValue(payload))
            client.SetAttribute("MaxPackets", ns.UintegerValue(0))
            client.SetAttribute("Interval", ns.TimeValue(ns.MicroSeconds(interval_us)))
            nodes.Get(i).AddApplication(client)
            # staggered by 0.5 ms + 20 us per node: windows of interval_us hold one beacon per sender
            client.SetStartTime(ns.MicroSeconds(interval_us // 2 + 20 * i))
        sinks = []
        for i in range(1 if n_nodes == 2 else 0, n_nodes):
            local = ns.PacketSocketAddress()
            local.SetSingleDevice(devs.Get(i).GetIfIndex())
            local.SetProtocol(1)
            apps = ns.PacketSinkHelper("ns3::PacketSocketFactory", getattr(local, "operator Address")()).Install(
                nodes.Get(i))
            apps.Start(ns.Seconds(0.0))
            sinks.append(apps.Get(0).GetObject[ns.PacketSink]())
        return mobs, sinks

    def run_for(self, us: int) -> None:
        self.ns.Simulator.Stop(self.ns.MicroSeconds(us))
        self.ns.Simulator.Run()


def data_field_bits(sim: Ns3, psdu_bytes: int) -> int:
    """The bits ns-3's error model is applied to for the DATA field: its duration (ns-3) x 6 Mbit/s."""
    ns = sim.ns
    tv = ns.WifiTxVector()
    tv.SetMode(ns.WifiMode(MODE))
    tv.SetChannelWidth(10)
    tv.SetPreambleType(ns.WIFI_PREAMBLE_LONG)
    return round(ns.WifiPhy.GetPayloadDuration(psdu_bytes, tv, ns.WIFI_PHY_BAND_5GHZ).GetSeconds()
                 * link_phy.BEACON_RATE_BPS)


def truav_with_bits(distances, cfg, n_bits: int) -> np.ndarray:
    """link_phy's delivery probability with the success raised to n_bits instead of 8 x beacon_bytes."""
    ch = cfg.channel
    free = link_phy.fspl_db(np.asarray(distances, float), ch.carrier_hz)
    return sum(w * (1.0 - link_phy.coded_ber(link_phy.qpsk_ber(link_phy.snr_at(free + extra, ch)))) ** n_bits
               for w, extra in tx_offsets_db(cfg))


def tx_offsets_db(cfg) -> list[tuple[float, float]]:
    """(weight, extra loss dB) per link state: link_phy's UAV-UAV loss is free space plus this."""
    ch = cfg.channel
    if ch.model != "paper":
        return [(1.0, 0.0)]
    p = ch.a2a_los_probability
    return [(w, eta) for w, eta in ((p, ch.eta_los_db), (1.0 - p, ch.eta_nlos_db)) if w > 0]


def sweep(sim: Ns3, cfg, distances: np.ndarray, n_packets: int, seed: int, preamble_detection: bool = True):
    """ns-3 delivered counts per distance (mixed over the link states) and seconds per distance."""
    ch, ns = cfg.channel, sim.ns
    payload = cfg.links.beacon_bytes - PSDU_OVERHEAD_BYTES
    nf_db = 10 * math.log10(ch.noise_w / (BOLTZMANN_NS3 * 290.0 * WIDTH_HZ))
    ratio = np.zeros(len(distances))
    delivered = np.zeros(len(distances), int)
    seconds = np.zeros(len(distances))
    airtime = []
    for weight, extra_db in tx_offsets_db(cfg):
        ns.RngSeedManager.SetSeed(seed)
        ns.RngSeedManager.SetRun(1)
        mobs, sinks = sim.network(2, 10 * math.log10(ch.uav_tx_w * 1e3) - extra_db, ch.antenna_gain_dbi, nf_db,
                                  ch.carrier_hz, payload, INTERVAL_US, preamble_detection)
        sim.probe.Reset()
        sim.probe.Connect()
        for i, d in enumerate(distances):
            mobs[1].SetPosition(ns.Vector(float(d), 0.0, ALTITUDE_M))
            before = sinks[0].GetTotalRx()
            t = time.perf_counter()
            sim.run_for(n_packets * INTERVAL_US)
            seconds[i] += time.perf_counter() - t
            k = (sinks[0].GetTotalRx() - before) // payload
            ratio[i] += weight * k / n_packets
            delivered[i] += k
        if sim.probe.n_delay:
            airtime.append(sim.probe.delay_sum / sim.probe.n_delay)
        ns.Simulator.Destroy()
    return ratio, delivered, seconds, nf_db, payload, (airtime[0] if airtime else math.nan)


def lockstep_cost(sim: Ns3, cfg, n_uavs: int, ticks: int, seed: int) -> float:
    """Seconds per tick of a positions -> ns-3 -> counts round trip: move every UAV, simulate one beacon from
    each (a TICK_US window), read every receiver's count."""
    ch, ns = cfg.channel, sim.ns
    ns.RngSeedManager.SetSeed(seed)
    payload = cfg.links.beacon_bytes - PSDU_OVERHEAD_BYTES
    nf_db = 10 * math.log10(ch.noise_w / (BOLTZMANN_NS3 * 290.0 * WIDTH_HZ))
    mobs, sinks = sim.network(n_uavs, 10 * math.log10(ch.uav_tx_w * 1e3), ch.antenna_gain_dbi, nf_db, ch.carrier_hz,
                              payload, TICK_US)
    rng = np.random.default_rng(seed)
    heard = 0
    t = time.perf_counter()
    for _ in range(ticks):
        for m, (x, y) in zip(mobs, rng.uniform(0.0, 100.0, (n_uavs, 2))):
            m.SetPosition(ns.Vector(float(x), float(y), ALTITUDE_M))
        sim.run_for(TICK_US)
        heard = sum(s.GetTotalRx() for s in sinks) // payload
    cost = (time.perf_counter() - t) / ticks
    ns.Simulator.Destroy()
    return cost, heard / ticks / n_uavs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/figures/ns3-link-check", help="output prefix (.csv, .png)")
    ap.add_argument("--models", default="paper,3gpp-uma-av", help="channel.model values, comma-separated")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override, repeatable")
    ap.add_argument("--packets", type=int, default=2000, help="beacons per distance")
    ap.add_argument("--step", type=float, default=2.0, help="distance step (m)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--uavs", type=int, default=10, help="UAVs in the lock-step cost measurement (0: skip)")
    ap.add_argument("--ticks", type=int, default=500, help="ticks in the lock-step cost measurement")
    args = ap.parse_args()
    t_total = time.perf_counter()
    sets = parse_sets(args.set)

    sim = Ns3()
    print(f"ns-3 imported in {sim.import_s:.1f} s")
    rows, panels, summary = [], [], []
    for model in args.models.split(","):
        over = {k: dict(v) for k, v in sets.items()}
        over.setdefault("channel", {})["model"] = model
        over.setdefault("links", {})["model"] = "channel"
        cfg = load_config(None, over)
        if cfg.links.beacon_bytes <= PSDU_OVERHEAD_BYTES:
            raise SystemExit(f"links.beacon_bytes must exceed {PSDU_OVERHEAD_BYTES} (the ns-3 PSDU overhead)")
        # from 0 to 1.25 x the distance where link_phy's delivery has fallen below 1e-4
        fine = np.arange(0.0, link_phy.max_distance_m(cfg), 0.5)
        p_fine = link_phy.delivery_probability(fine, cfg)
        d_max = 1.25 * fine[np.flatnonzero(p_fine < 1e-4)[0]]
        distances = np.arange(0.0, d_max + args.step / 2, args.step)
        print(f"{model}: {len(distances)} distances 0-{distances[-1]:.0f} m, {args.packets} beacons each ...",
              flush=True)
        ratio, delivered, secs, nf_db, payload, air_ns3 = sweep(sim, cfg, distances, args.packets, args.seed)
        n_states = len(tx_offsets_db(cfg))
        truav = link_phy.delivery_probability(distances, cfg)
        n_bits = data_field_bits(sim, cfg.links.beacon_bytes)
        truav_bits = truav_with_bits(distances, cfg, n_bits)
        for d, r, k, s, p, pb in zip(distances, ratio, delivered, secs, truav, truav_bits):
            lo, hi = wilson(int(k), args.packets * n_states) if n_states == 1 else (math.nan, math.nan)
            rows.append(dict(model=model, distance_m=float(d), ns3_delivered=int(k), ns3_sent=args.packets * n_states,
                             ns3_ratio=float(r), ns3_lo95=lo, ns3_hi95=hi, truav_p=float(p),
                             truav_p_data_field_bits=float(pb),
                             ns3_seconds=round(float(s), 4)))
        diff = np.abs(ratio - truav)
        i = int(np.argmax(diff))
        air_truav = link_phy.airtime_s(cfg.links.beacon_bytes)
        res = dict(model=model, n_bits=n_bits, max_diff_bits=float(np.max(np.abs(ratio - truav_bits))),
                   max_diff=float(diff[i]), at_m=float(distances[i]), d50_ns3=crossing(distances, ratio),
                   d50_truav=link_phy.threshold_distance_m(cfg), s_per_distance=float(secs.mean()) / n_states,
                   airtime_ns3_us=air_ns3 * 1e6, airtime_truav_us=air_truav * 1e6, nf_db=nf_db, payload=payload,
                   extra_db=tx_offsets_db(cfg))
        summary.append(res)
        panels.append((model, cfg, distances, ratio, np.array([[r["ns3_lo95"], r["ns3_hi95"]] for r in rows
                                                                if r["model"] == model]), res))
        print(f"  RxNoiseFigure {nf_db:.3f} dB (noise {cfg.channel.noise_w:g} W), tx "
              f"{10 * math.log10(cfg.channel.uav_tx_w * 1e3):.2f} dBm, extra loss as tx offset {res['extra_db']}, "
              f"payload {payload} B + {PSDU_OVERHEAD_BYTES} B = PSDU {cfg.links.beacon_bytes} B")
        print(f"  max |ns-3 - TRUAV| = {res['max_diff']:.3f} at {res['at_m']:.0f} m; 50 % at ns-3 "
              f"{res['d50_ns3']:.1f} m, TRUAV {res['d50_truav']:.1f} m; airtime ns-3 {res['airtime_ns3_us']:.1f} us, "
              f"TRUAV {res['airtime_truav_us']:.1f} us; {res['s_per_distance'] * 1e3:.0f} ms per distance "
              f"({args.packets} beacons)", flush=True)
        print(f"  ns-3 applies the error model to the DATA field's {res['n_bits']} bits (SERVICE + PSDU + tail + pad), "
              f"link_phy to the PSDU's {8 * cfg.links.beacon_bytes}: with {res['n_bits']} bits, max |ns-3 - TRUAV| = "
              f"{res['max_diff_bits']:.3f}", flush=True)

    # preamble detection (ns-3's default ThresholdPreambleDetectionModel, 4 dB) off: does it matter?
    cfg0 = panels[-1][1]
    d0 = panels[-1][2]
    ratio_np, *_ = sweep(sim, cfg0, d0, args.packets, args.seed, preamble_detection=False)
    change = np.abs(ratio_np - panels[-1][3])
    print(f"  {cfg0.channel.model} without preamble detection: max |change| {float(change.max()):.3f} at "
          f"{float(d0[np.argmax(change)]):.0f} m; max |ns-3 - TRUAV| then "
          f"{float(np.max(np.abs(ratio_np - link_phy.delivery_probability(d0, cfg0)))):.3f}")
    for r in rows:
        if r["model"] == cfg0.channel.model:
            r["ns3_ratio_no_preamble_detection"] = float(ratio_np[list(d0).index(r["distance_m"])])

    tick = math.nan
    if args.uavs > 1:
        tick, heard = lockstep_cost(sim, cfg0, args.uavs, args.ticks, args.seed)
        print(f"lock-step round trip with {args.uavs} UAVs at random in 100 m x 100 m (move all, one beacon each, "
              f"read counts): {tick * 1e3:.2f} ms per tick (mean of {args.ticks}); {heard:.2f} beacons heard per UAV "
              f"per tick")

    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fields = list(rows[0]) + ["ns3_ratio_no_preamble_detection"]
    with open(out.with_suffix(".csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields)
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
    figure(panels, out.with_suffix(".png"), args.packets)
    total = time.perf_counter() - t_total
    print(f"wrote {out.with_suffix('.csv')} and {out.with_suffix('.png')}; total {total:.1f} s "
          f"(import {sim.import_s:.1f} s)")


def figure(panels, path: Path, n_packets: int) -> None:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, axes = plt.subplots(1, len(panels), figsize=(5.2 * len(panels), 4.0), sharey=True, squeeze=False)
    for ax, (model, cfg, d, ratio, ci, res) in zip(axes[0], panels, strict=True):
        dd = np.linspace(0.0, d[-1], 800)
        ax.plot(dd, link_phy.delivery_probability(dd, cfg), color="tab:blue", lw=1.6,
                label="TRUAV link_phy P_deliver(d)")
        err = np.clip(np.vstack([ratio - ci[:, 0], ci[:, 1] - ratio]), 0.0, None) if np.all(np.isfinite(ci)) else None
        ax.errorbar(d, ratio, yerr=err, fmt="o", ms=3.5, color="tab:red", capsize=2, lw=1,
                    label=f"ns-3 3.44, {n_packets} beacons per point (Wilson 95 %)")
        ax.axhline(0.5, color="0.7", lw=0.8, ls=":")
        loss = "free space" if model != "paper" else " / ".join(f"FSPL + {e:g} dB" for _, e in res["extra_db"])
        ax.set_title(f"{model} (UAV-UAV: {loss})\n"
                     f"50 % at {res['d50_truav']:.1f} m (TRUAV), {res['d50_ns3']:.1f} m (ns-3)",
                     fontsize=9.5)
        ax.set_xlabel("distance between the two UAVs (m)")
        ax.set_xlim(0, d[-1])
        ax.set_ylim(-0.03, 1.03)
        ax.grid(alpha=0.3)
        ax.text(0.02, 0.04, f"max |difference| {res['max_diff']:.3f} at {res['at_m']:.0f} m\n"
                f"airtime {res['airtime_ns3_us']:.0f} us (ns-3), {res['airtime_truav_us']:.0f} us (TRUAV)",
                transform=ax.transAxes, fontsize=8)
    axes[0][0].set_ylabel("beacon delivery probability")
    axes[0][0].legend(loc="center left", fontsize=8)
    fig.suptitle(f"802.11p 10 MHz 6 Mbit/s, {panels[0][1].links.beacon_bytes} B beacon, "
                 f"{panels[0][1].channel.uav_tx_w:g} W, noise {panels[0][1].channel.noise_w:g} W, "
                 f"{panels[0][1].channel.carrier_hz / 1e9:g} GHz", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


if __name__ == "__main__":
    main()

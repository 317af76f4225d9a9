"""The channel experiment: the schemes under the paper's channel and under 3GPP UMa-AV, with ideal and with
channel-driven beacon links (docs/results/channel-experiment.md).

    python docs/scripts/channel_experiment.py RUNS_DIR --out docs/figures/channel-experiment

RUNS_DIR holds four `truav experiment velocity --preset paper --speeds 15` runs (the page gives the
commands): paper-ideal and uma-ideal (truav, central, patrol), paper-channel and uma-channel (truav only:
the patrol sends no beacons and the central scheme's controller sees every UAV, so links change neither).
Prints the Markdown tables of the page (means with 95% intervals over seeds; paired differences on the
same seeds with their 95% intervals, or "not detectable at this size") and draws OUT.png.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from truav.stats import effect_text, mean_ci, paired_effect

SETTINGS = (("paper-ideal", "paper channel, ideal links"), ("paper-channel", "paper channel, channel links"),
            ("uma-ideal", "3GPP UMa-AV, ideal links"), ("uma-channel", "3GPP UMa-AV, channel links"))
SCHEMES = (("truav", "TRUAV"), ("central", "central SAC"), ("patrol", "patrol"))
METRICS = (("coverage_pct", "coverage (%)", 1.0, 1), ("pdr", "PDR (%)", 100.0, 1), ("delay_ms", "delay (ms)", 1.0, 0),
           ("energy_above_hover_j", "energy above hover (kJ/UAV)", 1e-3, 2))


def per_seed(run: Path) -> dict[str, dict[str, dict[int, float]]]:
    """{scheme: {metric: {seed: mean over the greedy evaluation episodes}}} of a run's finished cells."""
    out: dict[str, dict[str, dict[int, float]]] = {}
    for f in sorted((run / "cells").glob("*.npz")):
        scheme = f.stem.split("_v")[0]
        with np.load(f) as d:
            seeds = [int(s) for s in d["seeds"]]
            for key, *_ in METRICS:
                values = np.nanmean(d[f"eval/{key}"], axis=0)
                out.setdefault(scheme, {}).setdefault(key, {}).update(zip(seeds, values.tolist()))
    return out


def paired(a: dict[int, float], b: dict[int, float]):
    seeds = sorted(set(a) & set(b))
    return paired_effect([a[s] for s in seeds], [b[s] for s in seeds])


def main(runs_dir: Path, out: Path) -> None:
    data = {name: per_seed(runs_dir / name) for name, _ in SETTINGS if (runs_dir / name / "cells").is_dir()}
    print("| scheme | setting | seeds | " + " | ".join(label for _, label, _, _ in METRICS) + " |")
    print("|---|---|---|" + "---|" * len(METRICS))
    for scheme, slabel in SCHEMES:
        for name, label in SETTINGS:
            got = data.get(name, {}).get(scheme)
            if not got:
                continue
            cells = []
            for key, _, scale, digits in METRICS:
                m, h = mean_ci(np.array(list(got[key].values())) * scale, axis=0)
                cells.append(f"{float(m):.{digits}f} ± {float(h):.{digits}f}")
            print(f"| {slabel} | {label} | {len(got['coverage_pct'])} | " + " | ".join(cells) + " |")
    print()
    comparisons = [("TRUAV: channel links minus ideal, paper channel", "truav", "paper-ideal", "paper-channel"),
                   ("TRUAV: channel links minus ideal, 3GPP UMa-AV", "truav", "uma-ideal", "uma-channel")]
    comparisons += [(f"{slabel}: 3GPP UMa-AV minus paper channel (ideal links)", s, "paper-ideal", "uma-ideal")
                    for s, slabel in SCHEMES]
    comparisons += [("TRUAV minus patrol, paper channel", ("patrol", "truav"), "paper-ideal", "paper-ideal"),
                    ("TRUAV minus patrol, 3GPP UMa-AV", ("patrol", "truav"), "uma-ideal", "uma-ideal"),
                    ("TRUAV (channel links) minus patrol, 3GPP UMa-AV", ("patrol", "truav"), "uma-ideal",
                     "uma-channel")]
    print("| paired on the same seeds | " + " | ".join(label for _, label, _, _ in METRICS) + " |")
    print("|---|" + "---|" * len(METRICS))
    for title, scheme, a, b in comparisons:
        sa, sb = scheme if isinstance(scheme, tuple) else (scheme, scheme)
        if sa not in data.get(a, {}) or sb not in data.get(b, {}):
            continue
        cells = []
        for key, _, scale, digits in METRICS:
            ra = {s: v * scale for s, v in data[a][sa][key].items()}
            rb = {s: v * scale for s, v in data[b][sb][key].items()}
            cells.append(effect_text(paired(ra, rb), digits=digits, noun="seeds"))
        print(f"| {title} | " + " | ".join(cells) + " |")
    _designs(runs_dir)
    _figure(data, out)


# Beacon-dependent TRUAV designs (run as `--schemes truav --set ...`, ideal and channel links: RUNS_DIR/<run>-ideal
# and <run>-channel), at the paper's noise and at 1e-11 W, where beacons carry ~600 m instead of ~60 m.
DESIGNS = (("default state (nearest-neighbour distance level)", "paper", "quiet"),
           ("learner.neighbour_sectors=4", "sectors", "quietsec"), ("learner.w_overlap=1.0", "overlap", None),
           ("federated.every=10", "federated", "quietfed"))
NOISES = ((1, "noise 1e-9 W (paper)"), (2, "noise 1e-11 W"))


def _designs(runs_dir: Path) -> None:
    """Prints, per design and noise, channel links minus ideal links and the design minus the default state
    (all paired on the same seeds)."""
    def run(name, links):
        path = runs_dir / f"{name}-{links}"
        return per_seed(path).get("truav") if name and (path / "cells").is_dir() else None

    rows = []
    for col, noise in NOISES:
        default = DESIGNS[0][col]
        for label, *names in DESIGNS:
            name = names[col - 1]
            rows.append((f"{noise}: {label}, channel links minus ideal", run(name, "ideal"), run(name, "channel")))
        for label, *names in DESIGNS[1:]:
            name = names[col - 1]
            for links in ("ideal", "channel"):
                rows.append((f"{noise}: {label} minus default state, {links} links", run(default, links),
                             run(name, links)))
    rows = [r for r in rows if r[1] and r[2]]
    if not rows:
        return
    print("\n| TRUAV design, paper channel, paired on the same seeds | " +
          " | ".join(label for _, label, _, _ in METRICS) + " |")
    print("|---|" + "---|" * len(METRICS))
    for title, a, b in rows:
        cells = []
        for key, _, scale, digits in METRICS:
            ra = {s: v * scale for s, v in a[key].items()}
            rb = {s: v * scale for s, v in b[key].items()}
            cells.append(effect_text(paired(ra, rb), digits=digits, noun="seeds"))
        print(f"| {title} | " + " | ".join(cells) + " |")


def _figure(data, out: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    colours = ("C0", "C9", "C1", "C3")
    fig, axes = plt.subplots(1, len(METRICS), figsize=(15, 4.2))
    width = 0.2
    for ax, (key, label, scale, _) in zip(axes, METRICS):
        for k, (name, slabel) in enumerate(SETTINGS):
            for i, (scheme, _) in enumerate(SCHEMES):
                got = data.get(name, {}).get(scheme)
                if not got:
                    continue
                values = np.array(list(got[key].values())) * scale
                m, h = mean_ci(values, axis=0)
                x = i + (k - 1.5) * width
                ax.bar(x, float(m), width, color=colours[k], label=slabel if i == 0 or scheme == "truav" else None,
                       yerr=float(h), capsize=3, edgecolor="black", lw=0.4)
        ax.set_xticks(range(len(SCHEMES)), [s for _, s in SCHEMES])
        ax.set_ylabel(label)
        ax.grid(axis="y", alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    seen = dict(zip(labels, handles))
    fig.legend(seen.values(), seen.keys(), loc="lower center", ncol=4, frameon=False)
    fig.suptitle("Greedy evaluation on held-out traffic at 15 m/s, paper preset (5000 training episodes); "
                 "mean of 10 seeds, 95% intervals")
    fig.tight_layout(rect=(0, 0.08, 1, 0.95))
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out.with_suffix(".png"), dpi=110)
    print(f"\nwrote {out.with_suffix('.png')}")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs_dir", type=Path, help="directory holding paper-ideal, paper-channel, uma-ideal, uma-channel")
    ap.add_argument("--out", type=Path, default=Path("docs/figures/channel-experiment"), help="figure path (no suffix)")
    args = ap.parse_args()
    main(args.runs_dir, args.out)

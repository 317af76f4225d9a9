"""Path loss against horizontal distance for each channel model (docs/explanation/channel-models.md).

    python docs/scripts/channel_models_figure.py [docs/figures/channel_models.png]

One panel per model at UAV heights of 30, 100 and 200 m (TR 36.777 UMa-AV/UMi-AV need more than
22.5 m), carrier 5.9 GHz (the paper's). Air-to-ground to a vehicle on the ground for the paper's and
Al-Hourani's models; UAV to a 10 m RSU (the base station of TR 36.777) for the 3GPP ones. The
paper's model averages rates over LoS/NLoS, not losses: its panel shows the LoS and NLoS losses it
averages, with the LoS probability as the line's weight noted in the legend at 500 m.
"""

from __future__ import annotations

import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from truav.config import ChannelConfig  # noqa: E402
from world import channel_models as cm  # noqa: E402

FC, RSU_H = 5.9e9, 10.0
HEIGHTS = (30.0, 100.0, 200.0)
COLOURS = ("tab:blue", "tab:orange", "tab:green")


def main(out: str = "docs/figures/channel_models.png") -> None:
    d = np.linspace(1.0, 3000.0, 600)
    ch = ChannelConfig()
    fig, axes = plt.subplots(2, 3, figsize=(13, 7.5), sharex=True, sharey=True)
    panels = axes.ravel()
    for h, c in zip(HEIGHTS, COLOURS):
        dist = np.hypot(d, h)
        free = cm.fspl_db(dist, FC)
        p500 = float(cm.al_hourani_los_probability(cm.elevation_deg(500.0, h), ch.los_a, ch.los_b))
        panels[0].plot(d, free + ch.eta_los_db, color=c, label=f"{h:g} m LoS (P_LoS(500 m) = {p500:.2f})")
        panels[0].plot(d, free + ch.eta_nlos_db, color=c, ls=":", label=f"{h:g} m NLoS")
        panels[1].plot(d, cm.al_hourani_path_loss_db(d, h, FC, "urban"), color=c, label=f"{h:g} m urban")
        panels[1].plot(d, cm.al_hourani_path_loss_db(d, h, FC, "highrise-urban"), color=c, ls="--",
                       label=f"{h:g} m high-rise")
        for ax, model in zip(panels[2:5], ("3gpp-uma-av", "3gpp-umi-av", "3gpp-rma-av")):
            lo, hi = cm.TR36777_HEIGHTS[model]
            if lo < h <= hi:
                ax.plot(d, cm.tr36777_mean_path_loss_db(model, d, h, RSU_H, FC), color=c, label=f"{h:g} m mean")
                if np.any(cm.tr36777_los_probability(model, d, h) < 1.0):  # else LoS always: no NLoS to show
                    _, nlos = cm.tr36777_path_loss_db(model, d, h, RSU_H, FC)
                    ax.plot(d, nlos, color=c, ls=":", lw=0.8, label=f"{h:g} m NLoS")
        panels[5].plot(d, free, color=c, label=f"{h:g} m")
    titles = ("paper (vehicle-UAV; rates averaged)", "Al-Hourani 2014 (vehicle-UAV), mean",
              "TR 36.777 UMa-AV (UAV-RSU)", "TR 36.777 UMi-AV (UAV-RSU)", "TR 36.777 RMa-AV (UAV-RSU)",
              "free space (UAV-UAV of the new models)")
    for ax, title in zip(panels, titles):
        ax.set_title(title, fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    for ax in axes[1]:
        ax.set_xlabel("horizontal distance (m)")
    for ax in axes[:, 0]:
        ax.set_ylabel("path loss (dB), 5.9 GHz")
    fig.tight_layout()
    fig.savefig(out, dpi=100)


if __name__ == "__main__":
    main(*sys.argv[1:])

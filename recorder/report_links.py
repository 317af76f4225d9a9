"""``links.png`` of ``truav report``: what each receiver heard, per link (sender i -> receiver j).

The recorder hears every beacon (no fault plan filters its bus), so receiver-side loss, a partition or
beacons too late for their tick cannot be seen in what it recorded. The agents count what they heard
themselves: each health report carries ``heard`` (beacons heard so far from each UAV, after the link
filter). A link's delivery is receiver j's count of sender i's beacons (summed over j's incarnations:
a restarted agent counts from zero) over the beacons i sent up to j's last report (their send times in
the recording); beacons i sent while j was down count as not delivered: j did not hear them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from recorder.report_data import MAX_HEARD, Recording

DPI = 110
ANNOTATE_MAX = 32  # cells carry their percentage up to this many UAVs (readable at 20)


@dataclass
class Links:
    """Per-link counts, indexed [sender, receiver] over UAV ids 0..n-1."""

    heard: np.ndarray
    sent: np.ndarray
    receivers: np.ndarray  # bool per UAV: it reported counts

    @property
    def share(self) -> np.ndarray:
        """Delivered share per link; NaN on the diagonal, for receivers without counts and unsent links."""
        with np.errstate(divide="ignore", invalid="ignore"):
            share = np.where(self.sent > 0, self.heard / np.maximum(self.sent, 1), np.nan)
        share[:, ~self.receivers] = np.nan
        np.fill_diagonal(share, np.nan)
        return share

    def summary(self) -> str:
        share = self.share
        if np.isnan(share).all():
            return "no link with beacons sent"
        i, j = np.unravel_index(np.nanargmin(share), share.shape)
        return (f"delivery {np.nansum(self.heard[~np.isnan(share)]) / np.nansum(self.sent[~np.isnan(share)]):.1%} "
                f"over {int((~np.isnan(share)).sum())} links, lowest {share[i, j]:.1%} (UAV {i} -> UAV {j})")


def _send_times(rec: Recording, uav: int) -> np.ndarray:
    s = rec.beacons.get(uav)
    own = s.pub_ns if s is not None else []
    return np.sort(np.asarray([*own, *rec.batched_sent_ns.get(uav, [])], dtype=np.int64))


def link_delivery(rec: Recording) -> Optional[Links]:
    """The per-link counts of a recording whose agents reported what they heard; None if none did."""
    if not rec.heard:
        return None
    n = min(MAX_HEARD, max(max(u for u, _ in rec.heard) + 1, max(len(h) for _, h in rec.heard.values())))
    heard = np.zeros((n, n), np.int64)
    last_ns: dict[int, int] = {}
    for (j, _inc), (t_ns, counts) in rec.heard.items():
        if j < n:
            heard[:len(counts), j] += np.asarray(counts[:n], np.int64)
            last_ns[j] = max(last_ns.get(j, t_ns), t_ns)
    sent = np.zeros((n, n), np.int64)
    for i in range(n):
        times = _send_times(rec, i)
        for j, t_ns in last_ns.items():
            sent[i, j] = np.searchsorted(times, t_ns, side="right")
    receivers = np.zeros(n, bool)
    receivers[list(last_ns)] = True
    return Links(heard=heard, sent=sent, receivers=receivers)


def links_figure(rec: Recording, path: Path) -> Optional[str]:
    """The delivery matrix as a heat map (sender rows, receiver columns, percentages in the cells)."""
    links = link_delivery(rec)
    if links is None:
        return None
    from recorder.report_figures import _plt

    plt = _plt()
    share = links.share
    n = len(share)
    side = min(14.0, max(5.0, 0.42 * n + 2.0))
    fig, ax = plt.subplots(figsize=(side + 1.6, side + 0.6))
    cmap = plt.get_cmap("viridis").with_extremes(bad="0.85")
    mesh = ax.imshow(np.ma.masked_invalid(share) * 100, cmap=cmap, vmin=0, vmax=100, origin="upper")
    fig.colorbar(mesh, ax=ax, fraction=0.046, pad=0.03).set_label("% of the sender's beacons the receiver heard")
    if n <= ANNOTATE_MAX:
        size = 9 if n <= 10 else 7 if n <= 20 else 5
        for i in range(n):
            for j in range(n):
                v = share[i, j]
                text = "" if i == j else "n/a" if np.isnan(v) else f"{v * 100:.0f}"
                ax.text(j, i, text, ha="center", va="center", fontsize=size,
                        color="black" if np.isnan(v) or v > 0.6 else "white")
    step = max(1, n // 25)
    ax.set_xticks(range(0, n, step), [str(u) for u in range(0, n, step)], fontsize=8)
    ax.set_yticks(range(0, n, step), [str(u) for u in range(0, n, step)], fontsize=8)
    ax.set_xlabel("receiver UAV (its own count of beacons heard)")
    ax.set_ylabel("sender UAV")
    faults = sorted({f"{s.fault} on {s.target}" for s in rec.fault_spans()})
    ax.set_title("Beacon delivery per link: share of sender's beacons each receiver heard\n"
                 f"{links.summary()}; grey = no counts (n/a) or own link"
                 + (f"\nfaults in the run: {', '.join(faults[:4])}{' ...' if len(faults) > 4 else ''}"
                    if faults else ""), fontsize=9, loc="left")
    fig.tight_layout()
    fig.savefig(path, dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    return f"links: {int(links.receivers.sum())} receivers, {links.summary()}"

"""What a what-if branch writes: whatif.csv (per episode, recorded and branch outcome side by side) and
whatif.png (one panel per outcome metric, the branch's episodes shaded)."""

from __future__ import annotations

import csv
from pathlib import Path

from truav.csvio import cell
from recorder.resim_branch import OUTCOME_METRICS, BranchResult


def write_csv(result: BranchResult, path: Path) -> None:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["episode", "branched"] + [f"{k}_{side}" for k, _ in OUTCOME_METRICS
                                              for side in ("recorded", "branch")])
        for e, pairs in result.outcome_rows():
            w.writerow([e, int(e >= result.from_episode)] + [cell(v) for pair in pairs for v in pair])


def whatif_figure(result: BranchResult, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")  # files only
    import matplotlib.pyplot as plt

    rows = result.outcome_rows()
    episodes = [e for e, _ in rows]
    fig, axes = plt.subplots(1, len(OUTCOME_METRICS), figsize=(3.2 * len(OUTCOME_METRICS), 3.0), squeeze=False)
    for m, (ax, (_, name)) in enumerate(zip(axes[0], OUTCOME_METRICS)):
        ax.axvspan(result.from_episode - 0.5, max(episodes, default=0) + 0.5, color="0.92", lw=0,
                   label="after the branch")
        ax.plot(episodes, [pairs[m][0] for _, pairs in rows], "o-", color="tab:blue", label="recorded run")
        ax.plot(episodes, [pairs[m][1] for _, pairs in rows], "s--", color="tab:orange", label="branch")
        ax.set_title(name, fontsize=10)
        ax.set_xlabel("episode")
        ax.set_xticks(episodes)
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7, loc="best")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


__all__ = ["whatif_figure", "write_csv"]

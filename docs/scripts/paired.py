"""What the results scripts share: Markdown tables of means and paired differences over seeds (95% intervals),
and coverage-against-speed figures with 95% bands.

The scripts import it as a sibling (``from paired import ...``): Python puts a script's folder first on its path.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from truav.stats import effect_text, mean_ci, paired_effect


def head(first: str, labels: list[str]) -> list[str]:
    """A Markdown table's header and rule: ``first`` then a column per label."""
    return ["| " + " | ".join([first, *labels]) + " |", "|---" * (len(labels) + 1) + "|"]


def row(first: str, cells: list[str]) -> str:
    """A Markdown table's row."""
    return f"| {first} | " + " | ".join(cells) + " |"


def ci(values: np.ndarray) -> str:
    """``mean ± half-width`` of the 95% interval over seeds, one decimal."""
    return "{:.1f} ± {:.1f}".format(*mean_ci(values))


def diff(base: np.ndarray, other: np.ndarray) -> str:
    """``other - base`` paired per seed, with its 95% interval (truav.stats.effect_text), one decimal."""
    return effect_text(paired_effect(base, other), digits=1, noun="seeds")


def pyplot():
    """matplotlib's pyplot, drawing to files only (no display)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def save(fig, path: Path) -> None:
    """Lay ``fig`` out, write it to ``path`` and free it."""
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    pyplot().close(fig)


def speed_figure(cov: dict[tuple[str, float], np.ndarray], speeds: list[float], schemes, style: dict, path: Path,
                 title: str, top: float, mark=None, legend_cols: int | None = None) -> None:
    """Coverage against speed, a line and its 95% band per scheme ``(key, label)`` in ``style[key]`` = (colour,
    marker, line style); y from 0 to ``top``; ``mark(ax)`` adds to the axes; the legend in ``legend_cols``
    columns (default: one row)."""
    fig, ax = pyplot().subplots(figsize=(7, 4.2))
    x = np.array(speeds)
    for k, label in schemes:
        colour, marker, ls = style[k]
        m, h = (np.array(t) for t in zip(*(mean_ci(cov[k, v]) for v in speeds)))
        ax.fill_between(x, m - h, m + h, color=colour, alpha=0.15, lw=0)
        ax.plot(x, m, color=colour, marker=marker, ls=ls, label=label)
    if mark is not None:
        mark(ax)
    ax.set_xlabel("UAV speed (m/s)")
    ax.set_ylabel("coverage (%)")
    ax.set_xticks(x)
    ax.set_ylim(0, top)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper center", ncol=legend_cols or len(schemes), fontsize=8)
    ax.set_title(title, fontsize=9)
    save(fig, path)

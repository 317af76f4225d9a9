"""A scale for a run's numbers: the same scenario, seed and episode count flown in process by the
reference policies (hover: the UAVs stay where they start; claim: the stronger decentralized heuristic,
agents.claim_agent, with its sensing on, the bar a learner must clear; patrol: the hand-written baseline,
agents.patrol, its fused kernel), printed beside the run's coverage and PDR, the coverages on one line.

They take about 3 s at the demo's size on a quiet 2-core machine (1 s once a process has flown them), so
`truav-swarm up` computes them at its end unless --no-references. They fly without the run's
faults and without its bus: a scale for the result, not a replay of it. The oracle ceiling (what no
planner can beat) is too slow to run here; docs/results/reproduction.md ("The ceiling of each
scenario") gives it per preset.
"""

from __future__ import annotations

import time

import numpy as np

from truav import jsonio
from truav.stats import shown
from truav.config import Config

HEURISTIC = "claim"
"""The heuristic reference: the stronger of the built-in heuristics (agents/claim_agent.py)."""
REFERENCE_SCHEMES = ("hover", HEURISTIC, "patrol")
KINDS = {HEURISTIC: f"agent:{HEURISTIC}"}
"""The trainer's controller kind of a reference named otherwise (the heuristic is an agents.api class)."""
SAID = {HEURISTIC: f"the heuristic {HEURISTIC}"}
"""How the coverage line names a reference, where its name alone does not say what it is."""
CEILING_DOC = "docs/results/reproduction.md, \"The ceiling of each scenario\""


def reference_metrics(cfg: Config, seed: int, episodes: int) -> dict:
    """Mean coverage (%) and PDR over ``episodes`` episodes of seed ``seed``, per reference scheme, and the
    seconds it took."""
    from agents.spread_agent import with_sensing  # the heuristic flies with its sensing on
    from truav.analysis.trainer import run_chunk

    started = time.monotonic()
    out: dict = {"seed": seed, "episodes": episodes}
    for name in REFERENCE_SCHEMES:
        metrics = run_chunk(KINDS.get(name, name), with_sensing(name, cfg), [seed], episodes, train=False).metrics
        out[name] = {key: _mean(list(np.ravel(metrics[key]))) for key in ("coverage_pct", "pdr")}
    out["elapsed_s"] = round(time.monotonic() - started, 2)
    return out


def run_metrics(world: dict | None) -> dict | None:
    """The run's own mean coverage and PDR over its finished episodes (world.json), None without any."""
    episodes = (world or {}).get("episodes") or []
    if not episodes:
        return None
    return {name: _mean([jsonio.num(e.get(name)) for e in episodes]) for name in ("coverage_pct", "pdr")}


def _mean(values: list[float]) -> float:
    """The mean of the finite values; NaN (shown as "no data") when there are none, without numpy's warning."""
    finite = [v for v in values if np.isfinite(v)]
    return float(np.mean(finite)) if finite else float("nan")


def references_line(scheme: str, world: dict | None, refs: dict | None, why_not: str | None, faults: bool) -> str:
    """The summary's lines: the run's coverage beside the references' on the first, then where they were flown and
    the PDRs; or the run's numbers and why there are no references."""
    own = run_metrics(world)
    if own is None:
        return "references: none (no episode finished)"
    if refs is None:
        return f"coverage {shown(own['coverage_pct'], '.1f', '%')}, PDR {shown(own['pdr'], '.3f')} " \
               f"(references not computed: {why_not})"
    n, names = refs["episodes"], [k for k in REFERENCE_SCHEMES if k in refs]
    return (f"coverage: this swarm ({scheme}) {shown(own['coverage_pct'], '.1f', '%')}, "
            + ", ".join(f"{SAID.get(k, k)} {shown(refs[k]['coverage_pct'], '.1f', '%')}" for k in names)
            + f"\n  references on the same scenario, seed {refs['seed']}, {n} episode{'s' if n != 1 else ''}"
            + (", without the faults" if faults else "") + f" (flown in process, {refs['elapsed_s']:.1f} s); "
            + f"PDR: this swarm {shown(own['pdr'], '.3f')}, "
            + ", ".join(f"{k} {shown(refs[k]['pdr'], '.3f')}" for k in names)
            + f"; the oracle ceiling: {CEILING_DOC}")


def references_for(cfg: Config, scheme: str, seed: int, world: dict | None, wanted: bool) -> tuple[dict | None, str | None]:
    """(references, None) or (None, why they were not computed)."""
    if not wanted:
        return None, "--no-references"
    if scheme in REFERENCE_SCHEMES:
        return None, f"the run flew {scheme}, itself a reference"
    episodes = len((world or {}).get("episodes") or [])
    if not episodes:
        return None, "no episode finished"
    try:
        return reference_metrics(cfg, seed, episodes), None
    except Exception as exc:  # a scale for the numbers must never cost the run its summary
        return None, f"{type(exc).__name__}: {exc}"

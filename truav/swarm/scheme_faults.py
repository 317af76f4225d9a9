"""`truav experiment faults --schemes truav central patrol`: the comparative stress test.

Every scheme flies real swarm runs (router, world, agent processes, and the
controller for central; real time) of the same seed under the same fault levels:

- link loss: a share p of every message on the schemes' radio links lost at the
  receiver: beacons (truav; patrol only at deployment), state uploads and
  commands (central, each direction on its own draw);
- link latency: the same links delayed by a fixed time;
- process crash: one process SIGKILLed at 20% of the run and restarted after a
  share of the run has passed (at 0.8: never): agent 0 for truav and patrol,
  the controller for central;
- partition: from 20% of the run, for a share of it (at 0.8: to the end), UAVs 0..n//2-1 cannot hear the
  others nor be heard by them (under central the controller stays with the rest: the first UAVs lose it).

One plan per level serves every scheme (a fault on another scheme's links
matches nothing), so the schemes meet the same faults with the same seeds. The
policies: truav flies a greedy Q-table and central a greedy trained actor, each
trained in process first (or given: --qtable, --policy); the patrol needs none.
Two learning variants of TRUAV start from the same Q-table and go on learning
online over ``learn_episodes`` episodes, exploring at ``learner.epsilon_end`` (where the
training ended; a swarm's episodes count from 0, and epsilon_start would fly them at random):
``federated`` shares Q rows after every
episode (``federated.every``, 1 unless the config sets it; the shares on
``uav/*/qshare/*`` are one of the links the faults hit), ``truav_online``
shares nothing (the federated one's counterpart: what the beacon faults alone
cost a learning swarm).
``spread``, the decentralized heuristic (agents/spread_agent.py, the bar a learner must clear), flies with its
sensing on (agents.spread_agent.with_sensing) and, like any other agent class, as follows.
Any other name in ``schemes`` is an agents.api class (pkg.module:Class or a registered name): trained in
process first (``truav train --agent`` for ``train_episodes["truav"]`` episodes, its agent.npz under
policy-<name>/), then flown greedily as one process per UAV (``up --agent NAME --qtable``), its crash
hitting UAV 0 as TRUAV's does.
Writes comparison.csv (tidy: scheme, kind, level and the metrics) and one figure
per metric, comparison-<metric>.png (panels loss, latency, crash; a line per scheme).
"""

from __future__ import annotations

import csv
import json
import math
import os
import re
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from truav.config import Config
from truav.stats import effect_text, paired_effect
from truav import jsonio
from truav.csvio import row_cells

SCHEMES = ("truav", "central", "patrol", "federated", "truav_online")
LEARNING = ("federated", "truav_online")
"""The schemes that fly the TRUAV table learning online (not greedy) over CompareSize.learn_episodes."""
KINDS = (("loss", "link loss (%)", 100.0), ("latency", "link latency (ms)", 1.0),
         ("crash", "process down (% of the run)", 100.0), ("partition", "UAVs 0-1 cut off (% of the run)", 100.0))
METRICS = (("coverage_pct", "coverage (%)", 1.0), ("pdr", "PDR (%)", 100.0), ("delay_ms", "relay delay (ms)", 1.0),
           ("energy_j", "energy (kJ/UAV/episode)", 1e-3), ("missed_actions", "missed actions (% of UAV-ticks)", 100.0))
CRASH_AT = 0.2
"""Share of the run after which the crash fault kills its process and the partition starts."""
LINK_KEYS = ("uav/*/beacon", "uav/*/state", "controller/cmd/*", "uav/*/qshare/*")
"""The schemes' radio links: TRUAV's (and the patrol's deployment) beacons, central's uplink and downlink,
federated TRUAV's Q shares."""
FEDERATED_COLUMNS = ("shares_sent", "shares_merged", "shares_refused", "shares_missing")
"""Federated TRUAV's share counts in every row (0 for the schemes that share nothing)."""


@dataclass(frozen=True)
class CompareSize:
    loss: tuple[float, ...]
    latency_ms: tuple[float, ...]
    down_share: tuple[float, ...]
    episodes: int
    steps: int
    train_episodes: dict[str, int]
    learn_episodes: int
    """Episodes of the learning schemes' runs: several, so that shares after the first ones are merged and
    flown (a share comes after an episode)."""
    partition_share: tuple[float, ...] = ()
    """Shares of the run the partition lasts (0: no partition; at 0.8 to the end)."""


SIZES = {
    # 3 episodes a point even when quick: each effect's interval is paired over them (1 would give none)
    "quick": CompareSize((0.0, 0.25, 0.5), (0.0, 250.0, 500.0), (0.0, 0.4, 0.8), 3, 60, {"truav": 200, "central": 150}, 4,
                         (0.0, 0.4, 0.8)),
    "full": CompareSize((0.0, 0.1, 0.3, 0.5), (0.0, 100.0, 300.0, 500.0), (0.0, 0.2, 0.4, 0.8), 2, 100,
                        {"truav": 2000, "central": 500}, 4, (0.0, 0.2, 0.4, 0.8)),
}


def is_agent_class(scheme: str) -> bool:
    """A name that is not one of SCHEMES: an agents.api class (checked by the command line)."""
    return scheme not in SCHEMES


def file_name(scheme: str) -> str:
    """The scheme in a file name (an agent class's name holds ':')."""
    return re.sub(r"[^A-Za-z0-9_.-]", "-", scheme)


def episodes_of(size: CompareSize, scheme: str) -> int:
    return size.learn_episodes if scheme in LEARNING else size.episodes


def run_seconds(size: CompareSize, rate_hz: float, scheme: str = "truav") -> float:
    """Wall time of one run's ticks: every step and every episode's `done` tick."""
    return episodes_of(size, scheme) * (size.steps + 1) / rate_hz


def plan_text(scheme: str, kind: str, level: float, run_s: float, n_uavs: int = 5) -> str:
    """The plan of one fault level, for ``scheme`` (only the crash target and the controller's side of a partition
    depend on it) and a swarm of ``n_uavs``."""
    if level == 0.0:
        return ""
    if kind == "loss":
        return "".join(f'[[fault]]\nkind = "loss"\nstart = 0.0\nprobability = {level}\nkeys = "{k}"\n\n'
                       for k in LINK_KEYS)
    if kind == "latency":
        return "".join(f'[[fault]]\nkind = "latency"\nstart = 0.0\nfixed_ms = {level}\nkeys = "{k}"\n\n'
                       for k in LINK_KEYS)
    if kind == "partition":
        cut = max(1, n_uavs // 2)
        rest = (['"controller"'] if scheme == "central" else []) + [str(u) for u in range(cut, n_uavs)]
        until = "" if CRASH_AT + level >= 1.0 else f"duration = {level * run_s:.3f}\n"
        return (f'[[fault]]\nkind = "partition"\nstart = {CRASH_AT * run_s:.3f}\n{until}'
                f'groups = [[{", ".join(str(u) for u in range(cut))}], [{", ".join(rest)}]]\n')
    target = 'target = "controller"' if scheme == "central" else "uav = 0"
    restart = "" if CRASH_AT + level >= 1.0 else f"restart_after = {level * run_s:.3f}\n"
    return f'[[fault]]\nkind = "crash"\nstart = {CRASH_AT * run_s:.3f}\n{target}\n{restart}'


def points(size: CompareSize, schemes: tuple[str, ...]) -> list[tuple[str, str, float]]:
    """(scheme, kind, level) of every swarm run; level 0 is one no-fault run per scheme."""
    out = []
    for scheme in schemes:
        out.append((scheme, "none", 0.0))
        for kind, levels in (("loss", size.loss), ("latency", size.latency_ms), ("crash", size.down_share),
                             ("partition", size.partition_share)):
            out += [(scheme, kind, x) for x in levels if x > 0]
    return out


def train_central(cfg: Config, out: Path, episodes: int, seed: int) -> Path:
    """A centralized SAC trained in process for the swarm's controller to fly (one seed)."""
    from truav.analysis import runio
    from truav.analysis.trainer import run_chunk
    run = out / "policy-central"
    run.mkdir(parents=True, exist_ok=True)
    result = run_chunk("central", cfg, [seed], episodes)
    runio.write_config(run, cfg)
    runio.write_metrics(run / runio.METRICS_FILE, [seed], result.metrics)
    runio.write_policy(run, [seed], result.policy, cfg)
    return run


def train_agent(cfg: Config, out: Path, name: str, episodes: int, seed: int) -> Path:
    """An agents.api class trained in process (one seed), as `truav train --agent NAME` does, for its swarm
    to fly; kept for a re-run (its agent.npz is written last)."""
    from truav.analysis import agent_loader, runio
    from truav.analysis.agent_run import AGENT_FILE, write_agent_state
    from truav.analysis.trainer import run_chunk
    run = out / f"policy-{file_name(name)}"
    if (run / AGENT_FILE).is_file():
        return run
    from agents.spread_agent import with_sensing  # the heuristic flies with its sensing on
    cfg = with_sensing(name, cfg)
    run.mkdir(parents=True, exist_ok=True)
    cls = agent_loader.resolve(name, flag="--schemes")
    result = run_chunk(agent_loader.AGENT_KIND_PREFIX + name, cfg, [seed], episodes)
    runio.write_config(run, cfg)
    runio.write_metrics(run / runio.METRICS_FILE, [seed], result.metrics)
    write_agent_state(run, name, cls.api_version, [seed], result.policy, result.uav_pos, cfg)
    return run


def run_point(cfg: Config, out: Path, seed: int, policies: dict[str, str | None], rate_hz: float, size: CompareSize,
              total: int, n: int, scheme: str, kind: str, level: float) -> str:
    """One swarm run (kept if finished: truav.swarm.fault_sweep.swarm_point); its summary.json text."""
    from truav.swarm.fault_sweep import swarm_point
    from truav.swarm.supervisor import SwarmOptions, run_swarm
    name = f"{file_name(scheme)}-{kind}-{level:g}"

    def start() -> int:
        text = plan_text(scheme, kind, level, run_seconds(size, rate_hz, scheme), cfg.scenario.n_uavs)
        plan = None
        if text:
            plan = out / f"{name}.toml"
            plan.write_text(text)
        learning = scheme in LEARNING
        run_cfg = cfg
        if learning:  # going on from the trained table: exploring as its training ended, not from epsilon_start
            run_cfg = cfg.replace(federated={"every": (cfg.federated.every or 1) if scheme == "federated" else 0},
                                  learner={"epsilon_start": cfg.learner.epsilon_end})
        from truav.analysis.agent_loader import AGENT_KIND_PREFIX
        from agents.spread_agent import with_sensing  # the heuristic flies with its sensing on
        run_cfg = with_sensing(scheme, run_cfg)
        agent = is_agent_class(scheme)
        return run_swarm(run_cfg, SwarmOptions(
            run=f"cmp{n}", seed=seed, episodes=episodes_of(size, scheme), rate_hz=rate_hz, out=str(out / name),
            plot=False, quiet=True, fault_plan=str(plan) if plan else None,
            force=True,  # unfinished: afresh, its partial files replaced
            references=False,
            scheme="truav" if learning else AGENT_KIND_PREFIX + scheme if agent else scheme,
            qtable=policies[scheme] if agent else policies["truav"] if scheme == "truav" or learning else None,
            greedy=scheme == "truav" or agent,
            policy=policies["central"] if scheme == "central" else None,
            max_missed_share=1.0))  # a point whose actions went missing is a result here, not a failure
    return swarm_point(n, total, name, out / name, episodes_of(size, scheme), f"{scheme}: {kind} {level:g}", start)


def row_of(scheme: str, kind: str, level: float, summary: dict, n_uavs: int) -> dict:
    world = summary.get("world") or {}
    eps = world.get("episodes") or []
    row = {"scheme": scheme, "kind": kind, "level": level}
    for key, _, _ in METRICS[:-1]:
        vals = [jsonio.num(e.get(key)) for e in eps]
        row[key] = float(np.nanmean(vals)) if vals else math.nan
    acting = world.get("ticks", 0) - len(eps)
    held = sum(((a or {}).get("commands") or {}).get("held", 0) for a in summary.get("agents") or [])
    # No fresh decision of the scheme's policy for that UAV and tick: no action in time (the world hovered it),
    # an autopilot's hover without commands, or a held stale command (central).
    missed = world.get("deadline_misses", 0) + world.get("hover_answers", 0) + held
    row["missed_actions"] = missed / (acting * n_uavs) if acting > 0 else math.nan
    fed = [a["federated"] for a in summary.get("agents") or [] if a and a.get("federated")]
    for column, key in zip(FEDERATED_COLUMNS, ("shares_sent", "shares_merged", "refused", "missing")):
        row[column] = sum(sum(f[key].values()) if key == "refused" else f[key] for f in fed)
    return row


def run_comparison(cfg: Config, size_name: str | CompareSize, out: Path, schemes: tuple[str, ...], seed: int = 0,
                   qtable: str | None = None, policy: str | None = None, rate_hz: float = 10.0,
                   keep_steps: bool = False, executor: str = "local", address: str | None = None) -> list[Path]:
    """Every scheme's swarm runs at every point of ``size_name`` (a name of SIZES, or a size of the caller's)."""
    size = SIZES[size_name] if isinstance(size_name, str) else size_name
    out.mkdir(parents=True, exist_ok=True)
    if not keep_steps:
        cfg = cfg.replace(scenario={"steps_per_episode": size.steps})
    policies: dict[str, str | None] = {"truav": qtable, "central": policy}
    if ("truav" in schemes or set(LEARNING) & set(schemes)) and qtable is None:
        from truav.swarm.fault_sweep import train_policy
        n = size.train_episodes["truav"]
        print(f"training TRUAV in process ({n} episodes) for the swarm to fly", flush=True)
        policies["truav"] = str(train_policy(cfg, out, n, seed))
    if "central" in schemes and policy is None:
        n = size.train_episodes["central"]
        print(f"training the centralized SAC in process ({n} episodes) for the controller to fly", flush=True)
        policies["central"] = str(train_central(cfg, out, n, seed))
    for name in filter(is_agent_class, schemes):
        n = size.train_episodes["truav"]
        print(f"training {name} in process ({n} episodes) for its swarm to fly", flush=True)
        policies[name] = str(train_agent(cfg, out, name, n, seed))
    todo = points(size, schemes)
    point = partial(run_point, cfg, out, seed, policies, rate_hz, size, len(todo))
    if executor == "ray":
        from truav.experiments.ray_executor import run_points_on_ray
        from truav.swarm.fault_sweep import SWARM_CPUS
        cpus = os.cpu_count() or 1
        texts = run_points_on_ray(lambda p: point(*p), [(n, *p) for n, p in enumerate(todo)], cpus, address,
                                  cpus_per_task=min(SWARM_CPUS, cpus))
    else:
        texts = [point(n, *p) for n, p in enumerate(todo)]
    rows = []
    per_episode = {}
    for (scheme, kind, level), text in zip(todo, texts):
        summary = json.loads(text)
        per_episode[scheme, kind, level] = {key: [jsonio.num(e.get(key)) * scale for e in
                                                  (summary.get("world") or {}).get("episodes") or []]
                                            for key, _, scale in METRICS[:-1]}
        row = row_of(scheme, kind, level, summary, cfg.scenario.n_uavs)
        for k in ([kind] if kind != "none" else [k for k, _, _ in KINDS]):  # the baseline is level 0 of every kind
            rows.append({**row, "kind": k})
    rows.sort(key=lambda r: (schemes.index(r["scheme"]), [k for k, _, _ in KINDS].index(r["kind"]), r["level"]))
    with open(out / "comparison.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(row_cells(r) for r in rows)
    (out / "policies.json").write_text(jsonio.dumps(policies, indent=1))
    text = comparison_effects(per_episode, schemes)
    print(text, flush=True)
    (out / "effects.txt").write_text(text + "\n")
    return [metric_figure(rows, schemes, key, label, scale, out / f"comparison-{key}.png",
                          title=f"{label}: {', '.join(schemes)} under the same faults, seed {seed}")
            for key, label, scale in METRICS]


def comparison_effects(per_episode: dict[tuple[str, str, float], dict[str, list[float]]], schemes) -> str:
    """Each scheme against the first at every point, and each fault point against the scheme's own no-fault
    run: differences paired over the episodes (the same seed: episode k drives the same traffic in every run),
    with their 95% interval or why there is none."""
    def line(label: str, a: list[float], b: list[float]) -> str:
        n = min(len(a), len(b))
        return f"  {label:<26}{effect_text(paired_effect(a[:n], b[:n]), noun='episodes')}"

    lines = ["effects paired over episodes, 95% t-interval:"]
    first = schemes[0]
    for (scheme, kind, level), values in per_episode.items():
        if scheme == first:
            continue
        base = per_episode.get((first, kind, level))
        if base is not None:
            lines.append(f"{scheme} - {first} at {kind} {level:g}:")
            lines += [line(label, base[key], values[key]) for key, label, _ in METRICS[:-1]]
    for (scheme, kind, level), values in per_episode.items():
        base = per_episode.get((scheme, "none", 0.0))
        if kind != "none" and base is not None:
            lines.append(f"{scheme}: {kind} {level:g} - no fault:")
            lines += [line(label, base[key], values[key]) for key, label, _ in METRICS[:-1]]
    return "\n".join(lines)


LINE_STYLES = ("-", "--", ":", "-.")


def metric_figure(rows: list[dict], schemes, key: str, label: str, scale: float, path: Path, title: str) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from truav.experiments.report import SCHEME_STYLE
    fig, axes = plt.subplots(1, len(KINDS), figsize=(13, 3.8), sharey=True)
    for ax, (kind, xlabel, xscale) in zip(axes, KINDS):
        for c, scheme in enumerate(schemes):
            pts = sorted((r for r in rows if r["scheme"] == scheme and r["kind"] == kind), key=lambda r: r["level"])
            x = np.array([p["level"] for p in pts]) * xscale
            y = np.array([p[key] for p in pts], dtype=float) * scale
            _, color, marker = SCHEME_STYLE.get(scheme, (scheme, f"C{c}", "o"))
            # Schemes often coincide (0 missed actions): each drawn smaller, dashed differently and on
            # top of the one before, so a series under another still shows around it.
            ax.plot(x, y, marker=marker, ms=max(10 - 2 * c, 4), mfc="none" if c == 0 else color, mew=1.4,
                    color=color, ls=LINE_STYLES[c % len(LINE_STYLES)], lw=max(2.6 - 0.5 * c, 0.8), label=scheme,
                    zorder=2 + c)
        ax.set_xlabel(xlabel)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel(label)
    axes[0].legend()
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path

"""How long `truav-swarm chaos --plan` takes, said before it starts (kept apart from chaos.py, which loads
matplotlib, so the command line can name the default without it)."""

from __future__ import annotations

PLAN_EPISODES = 6
"""Episodes of each run of `chaos --plan` by default: the effects are paired over them (a t-interval of 2 pairs
is 12.7 standard errors wide: no answer); 6 keeps a default run (two swarms of 100-step episodes at 10 Hz) at
about 3 minutes on the 2-core reference machine."""
CHAOS_MAX_MISSED_SHARE = 1.0
"""`chaos`'s --max-missed by default: its runs are not failed by their missed actions (a fault plan's crashes and
pauses miss many by design); chaos judges them itself: the baseline's against invariants.HOST_LOAD_MISSED_SHARE
(a warning), the faulted run's quiet tail after the heal (an invariant). A --max-missed given applies to both runs."""
START_STOP_S = 12.0
"""A swarm's start (router, world, agents, recorder) and orderly stop on the reference machine, measured; the
ticks come on top."""


def expected_s(episodes: int, steps: int, rate_hz: float, runs: int = 2) -> float:
    """Real-time runs: the ticks at ``rate_hz`` plus each run's start and stop."""
    return runs * (episodes * steps / rate_hz + START_STOP_S)


def announce(episodes: int, steps: int, rate_hz: float, lockstep: bool) -> str:
    """The line `chaos --plan` prints first."""
    what = f"2 runs (no faults, then the plan) of {episodes} episode(s) x {steps} steps"
    if lockstep:
        return f"chaos: {what} in lock-step (paced by the agents, not the clock); effects paired over the episodes"
    total = expected_s(episodes, steps, rate_hz)
    return (f"chaos: {what} at {rate_hz:g} Hz: about {total / 60:.0f} min {total % 60:02.0f} s; effects paired over "
            f"the episodes (--episodes: more give narrower intervals)")

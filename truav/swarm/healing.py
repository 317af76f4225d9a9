"""`truav-swarm up --restart`: the supervisor heals a swarm whose processes die.

An agent process (or the controller, scheme central) that dies mid-run on its
own (a non-zero exit or a signal, outside the fault plan, not on a shutdown)
is started again with its own command line after a backoff
(:func:`backoff_s`: 0.5 s, doubling, at most 8 s), and resumes from its last
checkpoint.  The router is started again at once on the same endpoint; every
client (world, agents, recorder, this supervisor) reconnects to it by itself.
After ``--restart-limit`` restarts of one process it stays down and the run
fails (something is wrong beyond a transient fault).  The world and the
recorder are never restarted: the world is the run's clock and its episode
state, and a new recorder could not append to the old file.

Lock-step: a restarted agent resumes from its checkpoint there too, but the
world went on without it while it was down (its UAV hovered), so the run is no
longer exactly what a clean run of the same seed gives; the summary warns so.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

RESTART_POLICIES = ("on-failure", "never")
DEFAULT_RESTART_POLICY = "on-failure"
DEFAULT_RESTART_LIMIT = 5
"""Restarts of one process before it is left down (and the run fails)."""
RESTART_BACKOFF_S = 0.5
RESTART_BACKOFF_MAX_S = 8.0
ROUTER_BACKOFF_MAX_S = 1.0
"""The router comes back fast: its clients give up after --router-timeout (10 s by default)."""
RESTART_RECORD = "restart"
"""The fault kind of the supervisor's restart messages on truav/<run>/fault/restart (the recording shows them)."""


def backoff_s(restarts_done: int, cap: float = RESTART_BACKOFF_MAX_S) -> float:
    """How long to wait before the next restart of a process restarted ``restarts_done`` times already."""
    return min(RESTART_BACKOFF_S * 2 ** restarts_done, cap)


@dataclass
class Restart:
    """One restart: what died, how, when it came back."""

    process: str
    cause: str  # "killed by SIGKILL", "exit code 1"
    died_s: float  # seconds since the supervisor started
    number: int  # 1 for the first restart of this process
    old_pid: int
    died_wall_ns: int = 0
    restarted_s: float | None = None
    new_pid: int | None = None
    restarted_wall_ns: int | None = None

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass
class Healer:
    """Which dead processes to restart, and when (the supervisor starts them)."""

    policy: str = DEFAULT_RESTART_POLICY
    limit: int = DEFAULT_RESTART_LIMIT
    restarts: list[Restart] = field(default_factory=list)  # done, in order
    pending: dict[str, tuple[float, Restart]] = field(default_factory=dict)  # name -> (due monotonic, restart)
    given_up: list[str] = field(default_factory=list)

    def count(self, name: str) -> int:
        return sum(r.process == name for r in self.restarts) + (name in self.pending)

    def died(self, name: str, pid: int, cause: str, since_s: float, now: float,
             cap: float = RESTART_BACKOFF_MAX_S) -> Restart | None:
        """A process died on its own: the Restart scheduled for it, or None (policy never, or limit reached)."""
        if self.policy == "never":
            return None
        done = self.count(name)
        if done >= self.limit:
            self.given_up.append(name)
            return None
        r = Restart(name, cause, round(since_s, 2), done + 1, pid, died_wall_ns=time.time_ns())
        self.pending[name] = (now + backoff_s(done, cap), r)
        return r

    def due(self, now: float) -> list[Restart]:
        """The scheduled restarts whose backoff has passed (removed from pending)."""
        ready = [name for name, (t, _) in self.pending.items() if t <= now]
        return [self.pending.pop(name)[1] for name in ready]

    def done(self, r: Restart, new_pid: int, since_s: float) -> None:
        r.new_pid, r.restarted_s, r.restarted_wall_ns = new_pid, round(since_s, 2), time.time_ns()
        self.restarts.append(r)

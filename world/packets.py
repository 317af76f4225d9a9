"""Per-vehicle bounded packet queues with a delivery deadline, as counts.

A queue is a ring of D = deadline_steps age slots per vehicle, shape
(B, N, D): slot (t % D) receives the packets born at step t. At the end of a
step the slot about to turn D steps old is emptied (those packets expire)
and becomes the arrival slot of the next step; nothing is shifted. Service
is FIFO, oldest slot first. Totals per vehicle are kept alongside, so no
step sums over D. The per-vehicle operations are numba functions called by
the world's step kernel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from truav import kernel_cache  # noqa: F401, I001 - numba's cache set up before numba loads a kernel
from numba import njit


@dataclass
class Queues:
    """Packet counts: slots (B, N, D) int64 and totals (B, N) int64."""

    slots: np.ndarray
    total: np.ndarray

    @classmethod
    def empty(cls, batch: int, n: int, deadline_steps: int) -> "Queues":
        return cls(np.zeros((batch, n, deadline_steps), np.int64), np.zeros((batch, n), np.int64))

    def clear(self) -> np.ndarray:
        """Empty all queues; returns how many packets were dropped per env (B,)."""
        left = self.total.sum(axis=-1)
        self.slots[:] = 0
        self.total[:] = 0
        return left


# Each operation works on row i of an env's (N, D) slots, indexed in place: a
# view slots[i] per vehicle and step would increment and decrement the whole
# batch array's shared reference count, a cache line every thread writes.
@njit(cache=True)
def arrive_row(slots, i, queued, t, count, limit):
    """Enqueue `count` packets born at step t into queue i, holding `queued`,
    up to the bound; returns how many were accepted."""
    accepted = min(count, limit - queued)
    slots[i, t % slots.shape[1]] += accepted
    return accepted


@njit(cache=True)
def serve_row(slots, i, t, want):
    """Remove up to `want` packets from queue i, oldest first. Returns
    (served, sum of their ages in steps)."""
    depth = slots.shape[1]
    served, age_sum = 0, 0
    for age in range(depth - 1, -1, -1):  # age a lives in slot (t - a) % depth
        if served >= want:
            break
        slot = (t - age) % depth
        take = min(slots[i, slot], want - served)
        slots[i, slot] -= take
        served += take
        age_sum += take * age
    return served, age_sum


@njit(cache=True)
def expire_row(slots, i, t):
    """End of step t: drop queue i's packets reaching the deadline; returns how many."""
    slot = (t + 1) % slots.shape[1]
    dropped = slots[i, slot]
    slots[i, slot] = 0
    return dropped


@njit(cache=True)
def arrive(slots, queued, t, count, limit):
    """arrive_row of one queue (D,)."""
    return arrive_row(slots.reshape((1, slots.size)), 0, queued, t, count, limit)


@njit(cache=True)
def serve(slots, t, want):
    """serve_row of one queue (D,)."""
    return serve_row(slots.reshape((1, slots.size)), 0, t, want)


@njit(cache=True)
def expire(slots, t):
    """expire_row of one queue (D,)."""
    return expire_row(slots.reshape((1, slots.size)), 0, t)

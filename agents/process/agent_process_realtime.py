"""What only a real-time agent does: answer the newest observation, send its beacon in its slot of the
tick (agents.beacon_schedule; the main loop sends it while it waits for the next observation), keep each peer's freshest beacon, and, with
range-limited beacons (``beacon_cell_m``), follow the map cells within range (agents.beacon_cells).

:class:`RealtimeBeacons` is a part of agents.process.agent_process.AgentNode (which also holds the lock-step
half, agents.process.agent_process_lockstep); it uses the node's bus, options, lock, stop event and peers gone.
"""

from __future__ import annotations

import logging
import queue
import time

from agents.beacon_cells import BeaconCells, CellFollower, subscription_radius_m
from agents.beacon_schedule import BeaconSchedule, sends_beacon
from truav.bus import transport
from truav.wire import keys, schema

log = logging.getLogger("truav.agent")

REALTIME_BEACON_MAX_AGE_TICKS = 10
"""Real time: a neighbour's beacon older than this many ticks (1 s at 10 Hz) is ignored."""


def realtime_inbox_capacity(n_uavs: int) -> int:
    """Messages a real-time agent's inbox holds before evicting the oldest: a few ticks of every peer's
    beacons (it drains once a tick), so a flood costs at most this many decodes per tick."""
    return max(transport.REALTIME_RECEIVE_RING, 4 * n_uavs)


class RealtimeBeacons:
    """The real-time half of an agent node: newest observation, beacon slot and thread, freshest beacons."""

    def _init_realtime(self) -> None:
        cfg, opts = self.cfg, self.opts
        self.stale_obs_skipped = 0
        """Real time: observations skipped because a newer one was already waiting (:meth:`_newest_obs`)."""
        self._beacons: dict[int, schema.Beacon] = {}  # real time: each peer's freshest beacon
        self._pending_beacon = None
        self._schedule = BeaconSchedule(opts.tick_period_s, opts.beacon_phase, opts.beacon_spread, opts.uav,
                                        self.n_uavs, slots=opts.beacon_slots)
        self._cells = None if opts.beacon_cell_m is None else BeaconCells(
            opts.beacon_cell_m, cfg.scenario.area_m, subscription_radius_m(cfg, opts.beacon_every,
                                                                           opts.beacon_max_age_ticks))
        if self._cells is not None and self._cells.radius_m == float("inf"):
            raise ValueError("beacon_cell_m: the state holds the nearest neighbour's direction at any distance "
                             "(learner.neighbour_sectors); range-limited beacons would change it")
        self._follower = None if self._cells is None else CellFollower(self._cells)
        self._cell_subs: dict = {}  # range-limited beacons: map cell -> its subscription handle
        self._own_pos = (0.0, 0.0)

    def _newest_obs(self, msg: schema.Obs) -> schema.Obs | None:
        """Real time: the world applies only the current tick's action, so an agent that fell behind
        (a slow spell, a flood) answers the newest observation and skips the older ones, counted,
        instead of answering each after its deadline and staying behind. None: stop."""
        while True:
            try:
                nxt = self._obs.get_nowait()
            except queue.Empty:
                return msg
            if nxt is None:
                return None
            # The newest tick is answered, whatever the arrival order (a delayed one can come after it).
            older, msg = (nxt, msg) if nxt.tick < msg.tick else (msg, nxt)
            if self.stale_obs_skipped == 0:
                log.info("uav %d: behind the world, answering tick %d and skipping tick %d (stale observations "
                         "are skipped from now on, counted in the stats)", self.opts.uav, msg.tick, older.tick)
            self.stale_obs_skipped += 1

    def _follow_cells(self, pos: tuple[float, float]) -> None:
        """Range-limited beacons: subscribe to the cells now within range of ``pos``, drop the others."""
        self._own_pos = pos
        add, drop = self._follower.move(*pos)
        for cell in drop:
            self._cell_subs.pop(cell).close()
        for cell in add:
            self._cell_subs[cell] = self.bus.feed(self._beacon_inbox, keys.beacons_in_cell(self.opts.run, cell))

    def _beacon_key(self, obs: schema.Obs) -> str:
        """This agent's beacon key for ``obs`` (range-limited beacons: its cell's, following the cells)."""
        o = self.opts
        key = keys.uav_beacon(o.run, o.uav)
        if self._cells is not None:
            self._follow_cells(obs.pos)
            key = keys.uav_beacon_in_cell(o.run, o.uav, self._cells.cell_of(*obs.pos))
        return key

    def _schedule_beacon(self, obs: schema.Obs, key: str, beacon: schema.Beacon) -> None:
        """Make the beacon due in this agent's slot of the tick (if it sends one): the main loop sends it then."""
        o = self.opts
        # The world stamps every observation right after its tick starts: the minimum over recent ticks is the
        # tick start (agents.beacon_schedule). (A tick subscription of its own cost a thread wake-up per tick.)
        self._schedule.observe(obs.tick, obs.t / 1e9)
        if obs.done or not sends_beacon(obs.tick, o.uav, o.beacon_every):  # done: no one acts on this tick
            return
        self._send_due_beacon()  # a beacon still waiting (this agent fell behind) goes out before it is replaced
        due = time.monotonic() + self._schedule.due(obs.tick) - time.time()  # world clock -> this host's monotonic
        self._pending_beacon = (due, key, beacon)

    def _beacon_wait_s(self) -> float | None:
        """Real time: how long the main loop may wait for an observation before the pending beacon is due."""
        pending = self._pending_beacon
        return None if pending is None else max(pending[0] - time.monotonic(), 0.0)

    def _send_due_beacon(self) -> None:
        """Send the pending beacon if it is due (main loop; one thread fewer to wake per tick than a sender's)."""
        pending = self._pending_beacon
        if pending is None or pending[0] > time.monotonic():
            return
        self._pending_beacon = None
        try:
            self.bus.publish(pending[1], pending[2])
        except RuntimeError:  # bus closed at shutdown
            pass

    def _keep_freshest_beacon(self, b: schema.Beacon) -> None:
        """A peer's beacon heard (under the node's lock): kept if it is its newest."""
        prev = self._beacons.get(b.uav)
        if prev is None or b.tick >= prev.tick:
            self._beacons[b.uav] = b

    def _realtime_peer_lost(self, uav: int) -> None:
        """Under the node's lock: a lost peer's beacon is not used."""
        self._beacons.pop(uav, None)

    def _realtime_beacons_in_range(self, tick: int) -> dict[int, schema.Beacon]:
        """Each peer's freshest beacon, if recent enough (and, range-limited, within the radius)."""
        oldest = tick - self.opts.beacon_max_age_ticks
        with self._lock:
            fresh = {j: b for j, b in self._beacons.items() if b.tick >= oldest}
        if self._cells is not None:  # beyond the radius a beacon cannot change the state (agents.beacon_cells)
            fresh = {j: b for j, b in fresh.items() if self._cells.in_range(self._own_pos, b.pos)}
        return fresh

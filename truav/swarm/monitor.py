"""What `truav-swarm up` sees on the bus: liveliness, step and episode metrics,
beacons (for tracks and control-plane figures) and shutdown requests (who asked)."""

from __future__ import annotations

import threading
import time
from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np

from agents.process.shared_beacons import batch_sender_verdict, split_batch
from truav.bus.inbox import Inbox
from truav.bus.transport import Bus
from truav.stats import shown
from truav.wire import keys, schema

CONTROL_SHUTDOWN = "shutdown"
MAX_KEPT = 100_000
"""Liveliness arrivals per identity and missed steps per UAV kept for the restarts' account (bounded)."""


@dataclass
class Monitor:
    """What the supervisor sees on the bus."""

    n_uavs: int
    alive: set = field(default_factory=set)
    ticks: list = field(default_factory=list)  # (monotonic time, tick)
    coverage: list = field(default_factory=list)  # (tick, %)
    hovering: list = field(default_factory=list)  # (tick, UAVs without an action)
    generated: float = 0.0
    delivered: float = 0.0
    energy: list = field(default_factory=list)
    episodes: list = field(default_factory=list)
    beacon_count: dict = field(default_factory=lambda: defaultdict(int))
    beacon_bytes: dict = field(default_factory=lambda: defaultdict(int))
    tracks: dict = field(default_factory=lambda: defaultdict(list))
    vehicles: list = field(default_factory=list)
    t0: float | None = None  # monotonic time of the world's tick 0
    period_s: float = 0.1
    first_beacon: float | None = None  # wall-clock seconds
    last_beacon: float | None = None
    shutdowns: list = field(default_factory=list)  # (monotonic time, sender) of every shutdown request heard
    lock: threading.Lock = field(default_factory=threading.Lock)
    beacon_inbox: Inbox | None = None
    control_inboxes: list = field(default_factory=list)  # scheme central: state uploads, commands
    control_count: dict = field(default_factory=lambda: defaultdict(int))  # kind -> messages
    control_bytes: dict = field(default_factory=lambda: defaultdict(int))  # kind -> payload bytes
    control_span: list = field(default_factory=list)  # [first, last] receive time (s) of any of them
    command_ticks: set = field(default_factory=set)  # ticks commands were heard for (every controller incarnation)
    live_up: dict = field(default_factory=lambda: defaultdict(list))  # identity -> monotonic times its token came
    step_times: list = field(default_factory=list)  # monotonic arrival of each step's metrics
    missed_at: dict = field(default_factory=lambda: defaultdict(list))  # uav -> (step arrival, ticks it missed)
    missed_total: dict = field(default_factory=dict)  # uav -> the world's last uav.<i>.missed total

    def attach(self, bus: Bus, run: str, central: bool = False, tracks_from_world: bool = False) -> None:
        """central: also measure the state uploads and commands; tracks_from_world: UAV tracks from the
        world's positions (schemes whose agents send no beacons), else from the beacons heard."""
        self.tracks_from_world = tracks_from_world
        self.run = run
        bus.subscribe(keys.metrics_step(run), self._on_step)
        bus.subscribe(keys.metrics_episode(run), self._on_episode)
        # Beacons are the bulk of the traffic: an inbox drained by poll() keeps this
        # process from being a 21st subscriber callback in every beacon's fan-out.
        # On a bus with receive rings (real time) a full inbox evicts instead of decoding a flood to compact.
        self.beacon_inbox = bus.inbox(keys.all_beacons(run), compact=bus.receive_ring is None)
        bus.feed(self.beacon_inbox, keys.all_beacons_in_cells(run))  # range-limited beacons (--beacon-cell)
        bus.feed(self.beacon_inbox, keys.all_beacon_batches(run))  # a process's beacons in one (--batch-beacons)
        if central:  # the control plane's real messages, measured as they cross the bus
            self.control_inboxes = [bus.inbox(key, compact=bus.receive_ring is None)
                                    for key in (keys.all_states(run), keys.all_commands(run))]
        bus.subscribe(keys.world_positions(run), self._on_positions)
        bus.subscribe(keys.world_tick(run), self._on_tick)
        bus.watch_liveliness(keys.all_alive(run), lambda k: self._live(k, True), lambda k: self._live(k, False))
        bus.subscribe(keys.control(run, CONTROL_SHUTDOWN), self._on_shutdown)

    def _on_shutdown(self, key, msg: schema.Control, raw, recv_ns) -> None:
        with self.lock:
            self.shutdowns.append((time.monotonic(), msg.src))

    def _live(self, key: str, up: bool) -> None:
        with self.lock:
            who = key.split("/alive/", 1)[-1]
            (self.alive.add if up else self.alive.discard)(who)
            if up and len(self.live_up[who]) < MAX_KEPT:  # a restart's "starting" phase ends here (restart_cost)
                self.live_up[who].append(time.monotonic())

    def _on_step(self, key, msg: schema.Metrics, raw, recv_ns) -> None:
        v = msg.values
        now = time.monotonic()
        with self.lock:
            self.ticks.append((now, msg.tick))
            self.step_times.append(now)
            self._note_missed(v, now)
            self.coverage.append((msg.tick, v.get("coverage_pct", 0.0)))
            self.hovering.append((msg.tick, v.get("hovering_uavs", 0.0)))
            self.generated += v.get("generated", 0.0)
            self.delivered += v.get("delivered", 0.0)
            self.energy.append(v.get("energy_j", 0.0))

    def _note_missed(self, values: dict, now: float) -> None:
        """The ticks each UAV missed at this step (its total went up), for the restarts' account."""
        for name, total in values.items():
            if not (name.startswith("uav.") and name.endswith(".missed")):
                continue
            uav = name[4:-7]
            if not uav.isdigit():
                continue
            uav, total = int(uav), int(total)
            new = total - self.missed_total.get(uav, 0)
            self.missed_total[uav] = total
            if new > 0 and len(self.missed_at[uav]) < MAX_KEPT:
                self.missed_at[uav].append((now, new))

    def _on_tick(self, key, msg: schema.Tick, raw, recv_ns) -> None:
        with self.lock:
            if self.t0 is None:
                self.t0 = time.monotonic() - msg.tick * self.period_s

    def _on_episode(self, key, msg: schema.Metrics, raw, recv_ns) -> None:
        with self.lock:
            self.episodes.append(dict(msg.values))

    def poll(self) -> None:
        """Take in the beacons heard since the last call (call it often: the inbox is bounded)."""
        if self.beacon_inbox is None:
            return
        heard = self.beacon_inbox.drain()
        control = [r for box in self.control_inboxes for r in box.drain()]
        with self.lock:
            for r in control:
                self.control_count[r.msg.KIND] += 1
                self.control_bytes[r.msg.KIND] += len(r.raw)
                if r.msg.KIND == schema.KIND_COMMAND:
                    self.command_ticks.add(r.msg.tick)
                t = r.recv_ns / 1e9
                self.control_span = [min(self.control_span[0], t), max(self.control_span[1], t)] \
                    if self.control_span else [t, t]
            for r in heard:
                if isinstance(r.msg, schema.Beacons):  # each beacon of a batch as if sent alone
                    if batch_sender_verdict(r.key, r.msg) is not None:
                        continue
                    beacons = [b for _, b in split_batch(r.key, r.msg, self.run)]
                    size = len(r.raw) / len(beacons)
                else:
                    beacons, size = [r.msg], len(r.raw)
                for msg in beacons:
                    self.beacon_count[msg.uav] += 1
                    self.beacon_bytes[msg.uav] += size
                    if not getattr(self, "tracks_from_world", False):
                        self.tracks[msg.uav].append(msg.pos)
                self.first_beacon = self.first_beacon or r.recv_ns / 1e9
                self.last_beacon = r.recv_ns / 1e9

    def _on_positions(self, key, msg: schema.Positions, raw, recv_ns) -> None:
        with self.lock:
            self.vehicles = list(msg.vehicles)
            if getattr(self, "tracks_from_world", False):
                for i, pos in enumerate(msg.uavs):
                    self.tracks[i].append(pos)

    def status_lines(self) -> list[str]:
        with self.lock:
            now = time.monotonic()
            recent = [t for t, _ in self.ticks if now - t <= 2.0]
            rate = len(recent) / 2.0
            tick = self.ticks[-1][1] if self.ticks else 0
            agents = sorted(a for a in self.alive if a.startswith("uav/"))
            misses = sum(h for _, h in self.hovering)
            cov = self.coverage[-1][1] if self.coverage else float("nan")
            pdr = self.delivered / self.generated if self.generated else float("nan")
            energy = np.mean(self.energy[-10:]) if self.energy else float("nan")
        return [f"tick {tick:6d}  {rate:5.1f} ticks/s  agents alive {len(agents)}/{self.n_uavs}  "
                f"missed actions {int(misses)}",
                f"coverage {shown(cov, '5.1f', '%')}  PDR so far {shown(pdr, '6.3f')}  "
                f"energy/UAV/step {shown(energy, '6.1f', ' J')}",
                "alive: " + (" ".join(a.split("/")[1] for a in agents) or "-")]

    def debug_line(self) -> str:
        """What the supervisor heard so far (its -v line)."""
        with self.lock:
            tick = self.ticks[-1][1] if self.ticks else None
            hovering = self.hovering[-1][1] if self.hovering else 0
            beacons, controls = sum(self.beacon_count.values()), sum(self.control_count.values())
            alive, shutdowns = sorted(self.alive), [s for _, s in self.shutdowns]
        return (f"heard step metrics up to tick {'-' if tick is None else tick} ({int(hovering)} UAVs hovering in it), "
                f"{beacons} beacons, {controls} uploads/commands; alive: {' '.join(alive) or '-'}; "
                f"shutdown requests from: {', '.join(shutdowns) or 'nobody'}")

    def control_plane(self) -> dict[str, float]:
        self.poll()
        with self.lock:
            n = sum(self.beacon_count.values())
            size = sum(self.beacon_bytes.values())
            span = (self.last_beacon - self.first_beacon) if n > 1 else float("nan")
            uavs = max(len(self.beacon_count), 1)
            ups, downs = self.control_count[schema.KIND_STATE], self.control_count[schema.KIND_COMMAND]
            up_b, down_b = self.control_bytes[schema.KIND_STATE], self.control_bytes[schema.KIND_COMMAND]
            cspan = self.control_span[1] - self.control_span[0] if len(self.control_span) == 2 else 0.0
            command_ticks = len(self.command_ticks)
        per_s = n / span if span and span > 0 else float("nan")
        return {"states": ups, "bytes_per_state": up_b / ups if ups else float("nan"),
                "commands": downs, "command_ticks": command_ticks, "bytes_per_command": down_b / downs if downs else float("nan"),
                "central_bytes_per_s": (up_b + down_b) / cspan if cspan > 0 else float("nan"),
                "beacons": n, "bytes_per_beacon": size / n if n else float("nan"),
                "beacons_per_s_total": per_s, "beacons_per_s_per_uav": per_s / uavs,
                "beacon_bytes_per_s_total": size / span if span and span > 0 else float("nan")}

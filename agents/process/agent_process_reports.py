"""What an agent node reports about itself: its health report on the bus (about once a second) and its
stats file at exit (steps, beacon latency, what its bus refused, what it sent, per incarnation).

:class:`AgentReports` is a part of agents.process.agent_process.AgentNode; it reads the node's counters.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from truav import jsonio
from truav.atomic import write_kept
from truav.wire import keys, schema

HEALTH_PERIOD_S = schema.HEALTH_PERIOD_S
"""How often an agent publishes its health report (what it refused, by reason and sender) on uav/<i>/health."""
SENT_KINDS = (schema.KIND_BEACON, schema.KIND_ACTION, schema.KIND_STATE, schema.KIND_HEALTH)
"""What an agent counts as sent in its stats file (``sent``, per incarnation)."""
MAX_INCARNATIONS_KEPT = 1000
"""Earlier incarnations a restarted agent keeps listing in its stats file (bounded)."""


class AgentReports:
    """Health reports and the stats file of an agent node."""

    def health(self) -> schema.Health:
        """This agent's health report: what its bus refused, by reason and (the most refused) sender. (First
        it takes in what the world told it it refused: its rejections wait for this, about once a second.)"""
        self._take_rejections()
        by_reason = sorted(self.bus.rejections.by_reason().items(), key=lambda kv: (-kv[1], kv[0]))
        by_sender: dict[str, int] = {}
        for per_sender in self.bus.rejections.as_dict().values():
            for sender, n in per_sender.items():  # a name a flood chose: shown in printable ASCII only
                shown = "".join(c if " " <= c <= "~" else "?" for c in sender)[:schema.MAX_SRC_LEN] or "?"
                by_sender[shown] = by_sender.get(shown, 0) + n
        top = sorted(by_sender.items(), key=lambda kv: (-kv[1], kv[0]))[:schema.MAX_HEALTH_SENDERS]
        return schema.Health(uav=self.opts.uav, last_tick=self._last_tick, steps=self.steps,
                             stale_obs_skipped=self.stale_obs_skipped,
                             rejected=dict(by_reason[:schema.MAX_HEALTH_REASONS]), senders=dict(top),
                             heard=self.heard_counts())

    def heard_counts(self) -> tuple[int, ...]:
        """Beacons heard so far from each UAV, by sender id (the health report's ``heard``)."""
        with self._lock:
            return tuple(self.heard_from.tolist())

    def _take_rejections(self) -> None:
        drain = getattr(self, "drain_rejections", None)
        try:
            if drain is not None:
                drain()
        except RuntimeError:  # bus closed at shutdown
            pass

    def publish_health(self) -> bool:
        """Publish one health report unless this node has stopped (a host's shared health thread calls it
        for each of its agents); False if it has, or its bus is closed."""
        with self._health_lock:
            if self._health_done or self._stop.is_set():
                return False
            try:
                self.bus.publish(keys.uav_health(self.opts.run, self.opts.uav), self.health())
            except RuntimeError:  # bus closed at shutdown
                return False
            return True

    def _health_loop(self) -> None:
        """About once a second (and at once, so `truav-swarm status` sees a fresh agent): the health report."""
        while True:
            try:
                self.bus.publish(keys.uav_health(self.opts.run, self.opts.uav), self.health())
            except RuntimeError:  # bus closed at shutdown
                return
            if self._stop.wait(HEALTH_PERIOD_S):
                return

    def latency_stats(self) -> dict[str, float]:
        with self._lock:
            lat = np.array(self._latency_ms)
        if lat.size == 0:
            return {"n": 0}
        return {"n": int(lat.size), "p50": float(np.percentile(lat, 50)), "p99": float(np.percentile(lat, 99)),
                "max": float(lat.max())}

    def _read_earlier_incarnations(self) -> list[dict]:
        """A restarted agent (resumed from its checkpoint) keeps the ``incarnations`` of the stats file its
        earlier processes of this run wrote; a SIGKILLed one wrote none, so it is not listed."""
        path = self.opts.stats_out
        if not (self.resumed and path and Path(path).is_file()):
            return []
        try:
            old = json.loads(Path(path).read_text())
        except (OSError, ValueError):
            return []
        earlier = old.get("incarnations") if isinstance(old, dict) and old.get("run") == self.opts.run else None
        return [e for e in earlier if isinstance(e, dict)][-MAX_INCARNATIONS_KEPT:] if isinstance(earlier, list) else []

    def sent(self) -> dict[str, int]:
        """What this process published, by kind: beacons, actions, state uploads (central), health reports."""
        sent = self.bus.stats().sent
        return {kind: sent.get(kind, 0) for kind in SENT_KINDS}

    def write_stats(self) -> None:
        if self.opts.stats_out:
            self._take_beacons()  # the last tick's beacons count too
            self._take_rejections()  # and the world's last rejections
            with self._lock:
                samples = [round(x, 3) for x in self._latency_ms]
                senders = list(self._latency_from)
            st = self.bus.stats()
            data = {"uav": self.opts.uav, "steps": self.steps, "stale_obs_skipped": self.stale_obs_skipped,
                    "out_of_order_obs": self.out_of_order_obs,
                    "refused_by_world": dict(self.refused_by_world),
                    **({"lockstep": self.inexact.as_dict()} if self.opts.lockstep else {}),
                    "beacon_latency_ms": self.latency_stats(),
                    "beacons_heard": list(self.heard_counts()),
                    "beacon_latency_samples_ms": samples, "beacon_latency_from": senders,
                    "bus": {"received": st.received, "filtered": st.filtered, "delayed": st.delayed,
                            "malformed": self.bus.dropped_malformed, "rejected": st.rejected},
                    "scheme": self.opts.scheme, **self.scheme_stats()}
            links = getattr(self.decision, "links", None)  # TRUAV's decision; an agent API class has none yet
            if links is not None and links.table.size:  # channel-driven links: per peer, what the channel let through
                data["channel_links"] = {str(j): {"heard": c[0], "lost": c[1], "expected": round(c[2], 6),
                                                  "variance": round(c[3], 6)}
                                         for j, c in sorted(self.decision.link_counts.items())}
            if getattr(self, "fed", None) is not None and self.fed.every > 0:
                data["federated"] = self.federated_stats()
            # what this process sent, to compare with a recording's (uav/<i>, kind, incarnation) streams
            me = {"inc": f"{self.bus.incarnation:016x}", "steps_from": self._steps_at_start, "steps_to": self.steps,
                  "sent": self.sent()}
            data.update(run=self.opts.run, incarnation=me["inc"], sent=me["sent"],
                        incarnations=[*self._earlier_incarnations, me])
            p = Path(self.opts.stats_out)
            text = jsonio.dumps(data).encode()
            write_kept(p, lambda f: f.write(text), self.say_no_space)

"""The supervisor's watch of a running swarm: the live status, processes that die (and their restarts,
truav.swarm.healing), the fault plan's kills and restarts, the router's restarts."""

from __future__ import annotations

import contextlib
import signal
import sys
import time

from truav.atomic import EXIT_NO_SPACE
from truav.bus.transport import Bus
from truav.lograte import Every
from truav.swarm import external
from truav.swarm.children import exit_text
from truav.swarm.healing import RESTART_BACKOFF_MAX_S, RESTART_RECORD, ROUTER_BACKOFF_MAX_S, Restart
from truav.swarm.restart_cost import MAX_DEATHS
from truav.wire import keys, schema
from truav.swarm.swarm_options import (RECORDER_START_TIMEOUT_S, ROUTER_RECONNECT_WAIT_S, ROUTER_START_TIMEOUT_S,
                                       RSS_PERIOD_S, STATUS_PERIOD_S, process_of)


class SwarmWatch:
    """The watch part of the supervisor's _Swarm (its state lives in _Swarm.__init__)."""

    def _plan_kill(self, who) -> None:
        name = process_of(who)
        p = self.children.procs.get(name)
        if p is not None:
            self.planned_exits.add(p.pid)
        if len(self.deaths) < MAX_DEATHS:
            self.deaths.append((name, time.monotonic()))
        if name == "router":
            self.router_down_ns = time.time_ns()
        self.children.send(name, signal.SIGKILL)

    def _plan_restart(self, who) -> None:
        name = process_of(who)
        if name == "router":
            ok, error = self._restart_router()
            if not ok:
                self.outcome.fail(f"the router could not be restarted on {self.endpoint} after the plan's crash: {error}")
        else:
            self.children.restart(name)

    def _restart_router(self) -> tuple[bool, str]:
        """The router again, with its own command line, on the same endpoint; its clients reconnect by themselves."""
        proc = self.children.start("router", self.children.argv["router"])
        ok, error = self._wait_router(proc, ROUTER_START_TIMEOUT_S)
        if ok:  # messages sent in between were lost on the wire: the soak's checker needs to know when
            self.router_outages.append((self.router_down_ns or time.time_ns(), time.time_ns()))
            self.router_down_ns = None
        return ok, error

    def _died(self, name: str, p) -> bool:
        """A process died on its own mid-run: say how, restart it if the policy allows; False if it stays down."""
        cause = exit_text(p.returncode)
        if len(self.deaths) < MAX_DEATHS:
            self.deaths.append((name, time.monotonic()))
        if name == "router":
            self.router_down_ns = time.time_ns()
        r = self.healer.died(name, p.pid, cause, self._since(), time.monotonic(),
                             cap=ROUTER_BACKOFF_MAX_S if name == "router" else RESTART_BACKOFF_MAX_S)
        last = self.children.last_line(name)
        what = "the router" if name == "router" else name
        if r is None:
            if self.opts.restart == "never" or name == "router":  # the router's failure is the caller's
                return False
            self.outcome.fail(f"{what} died {self.opts.restart_limit + 1} times ({cause} the last time; its last log "
                              f"line: {last}); not restarted again (--restart-limit {self.opts.restart_limit})")
            return False
        note = f"{what} died mid-run ({cause}) at {r.died_s:.1f} s; its last log line: {last}"
        self.outcome.warnings.append(note)
        due = self.healer.pending[name][0] - time.monotonic()
        print(f"{note}\n  restarting it in {max(due, 0):.1f} s (restart {r.number} of at most {self.opts.restart_limit})",
              flush=True)
        self._publish_restart(r, schema_phase="start")
        return True

    def _heal_due(self) -> None:
        with self.monitor.lock:
            ending = bool(self.monitor.shutdowns)
        for r in self.healer.due(time.monotonic()):
            if ending and r.process != "router":  # the run is ending: nothing to rejoin (the router still serves it)
                continue
            if r.process == "router":
                ok, error = self._restart_router()
                if not ok:
                    self.outcome.fail(f"the router died mid-run ({r.cause}) at {r.died_s:.1f} s and could not be "
                                      f"restarted on {self.endpoint}: {error}")
                    continue
            else:
                self.children.start(r.process, self.children.argv[r.process])
            self.healer.done(r, self.children.procs[r.process].pid, self._since())
            self.outcome.restarts.append(r.as_dict())
            print(f"restarted {r.process} (pid {r.new_pid}) at {r.restarted_s:.1f} s"
                  + (f" on {self.endpoint}" if r.process == "router" else " from its checkpoint"
                     if r.process != "controller" else ""), flush=True)
            if r.process == "router":  # its start was lost with the router: both phases once it is back
                self._await_router(ROUTER_RECONNECT_WAIT_S)
                self._publish_restart(r, schema_phase="start")
            self._publish_restart(r, schema_phase="end")

    def _await_router(self, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while self.bus is not None and time.monotonic() < deadline:
            with contextlib.suppress(Exception):
                if list(self.bus.session.info.routers_zid()):
                    return
            time.sleep(0.05)

    def _publish_restart(self, r: Restart, schema_phase: str) -> None:
        """In the recording (and `truav report`'s fault spans): a restart span from death to restart."""
        if self.bus is None:
            return
        target = keys.uav_identity(int(r.process[5:])) if r.process.startswith("agent") and r.process[5:].isdigit() \
            else r.process
        params = {"cause": r.cause, "restart": r.number, "old_pid": r.old_pid}
        if r.new_pid is not None:
            params["new_pid"] = r.new_pid
        with contextlib.suppress(Exception):  # a router going down under the put must not stop the watch
            self.bus.publish(keys.fault(self.opts.run, RESTART_RECORD),
                             schema.Fault(fault=RESTART_RECORD, phase=schema_phase, target=target, params=params))

    def _recorder_ready(self, bus: Bus) -> bool:
        proc = self.children.procs["recorder"]
        deadline = time.monotonic() + RECORDER_START_TIMEOUT_S
        while time.monotonic() < deadline:
            if proc.poll() is not None:
                self.outcome.fail(f"the recorder could not start: {self.children.last_line('recorder')}")
                return False
            if bus.alive(keys.alive_recorder(self.opts.run), timeout=0.3):
                return True
        self.outcome.fail(f"the recorder did not start within {RECORDER_START_TIMEOUT_S:.0f} s "
                          f"(see {self.children.log_dir}/recorder.log)")
        return False

    def _watch_external(self) -> bool:
        """The external UAVs (truav.swarm.external): before tick 0, wait for their liveliness tokens, a
        progress line every PROGRESS_EVERY_S, and fail past --external-wait; after it, note one that leaves
        before the run's end. False when the run must end."""
        opts, monitor = self.opts, self.monitor
        with monitor.lock:
            alive, ending = set(monitor.alive), bool(monitor.shutdowns)
        now = self._since()
        for i in opts.external:
            here = keys.uav_identity(i) in alive
            if here and i not in self.external_joined:
                self.external_joined[i] = now
                print(f"external uav/{i} joined at {now:.1f} s", flush=True)
            elif not here and i in self.external_joined and self.outcome.ticked and not ending \
                    and i not in self.external_left:
                self.external_left[i] = now
                note = f"external uav/{i} left at {now:.1f} s (its liveliness token went away); its UAV hovers"
                self.outcome.warnings.append(note)
                print(note, flush=True)
        missing = [i for i in opts.external if i not in self.external_joined]
        if missing and self.outcome.ticked:  # the world ticks only once every UAV is alive (its wait is longer)
            for i in missing:
                self.external_joined[i] = now
            return True
        if not missing:
            return True
        waited = time.monotonic() - self.external_since
        if waited >= opts.external_wait_s:
            self.outcome.fail(external.never_joined_text(missing, opts.external_wait_s, opts.run))
            return False
        if waited >= self.external_progress + external.PROGRESS_EVERY_S:
            self.external_progress = waited // external.PROGRESS_EVERY_S * external.PROGRESS_EVERY_S
            print(external.waiting_line(missing, waited, opts.external_wait_s), flush=True)
        return True

    def _watch(self) -> bool:
        """Until the world exits; False (with the failure noted) if the run must end early."""
        opts, monitor, children = self.opts, self.monitor, self.children
        tty = sys.stdout.isatty() and not opts.quiet
        drawn, last_print = 0, 0.0
        world = children.procs["world"]
        reported: set[int] = set()
        debug_every = Every(None, STATUS_PERIOD_S) if opts.verbose else None
        last_rss = 0.0
        while world.poll() is None:
            faults_pending = self.controller is not None and not self.outcome.ticked
            time.sleep(0.05 if faults_pending or not self.outcome.ticked else 0.2)
            monitor.poll()
            if opts.external and not self._watch_external():
                return False
            if debug_every is not None and debug_every.due():  # -v: what the bus showed, once a second
                print(f"debug: supervisor at {self._since():.1f} s: {monitor.debug_line()}", flush=True)
            if not self.outcome.ticked and monitor.t0 is not None:
                self.outcome.ticked = True
                if self.controller is not None:
                    self.controller.start(monitor.t0)
            for name in ("router", "recorder"):
                p = children.procs.get(name)
                if p is None or p.poll() is None or p.pid in reported:
                    continue
                reported.add(p.pid)
                if name == "router" and (p.pid in self.planned_exits or self._died(name, p)):
                    continue  # the plan or the healer restarts it
                what = "the router" if name == "router" else "the recorder"
                self.outcome.fail(f"{what} exited mid-run ({exit_text(p.returncode)}) at {self._since():.1f} s"
                                  + ("; the recording is incomplete" if name == "recorder" else "")
                                  + (f"; not restarted again (--restart-limit {self.opts.restart_limit})"
                                     if name in self.healer.given_up else ""))
                return False
            for name in self.fleet:
                p = children.procs.get(name)
                if p is None or p.poll() is None or p.pid in reported:
                    continue
                reported.add(p.pid)
                if not self.outcome.ticked:  # before the first tick: it could not start
                    self.outcome.fail(f"{name} could not start ({exit_text(p.returncode)}): "
                                      f"{children.last_line(name)}")
                    return False
                with monitor.lock:
                    shut_down = bool(monitor.shutdowns)
                if p.returncode in (0, EXIT_NO_SPACE) and shut_down:  # left on a shutdown request (a full disk: judged at the end)
                    continue
                if p.pid in self.planned_exits:
                    if opts.verbose or name == "controller":
                        print(f"{name} killed by the fault plan at {self._since():.1f} s"
                              + ("; the UAVs fly on without commands" if name == "controller" else ""), flush=True)
                    continue
                if p.returncode != 0 and not shut_down and self._died(name, p):
                    continue
                note = f"{name} exited mid-run ({exit_text(p.returncode)}); its last log line: " \
                    f"{children.last_line(name)}" + ("; the UAVs fly on without commands" if name == "controller" else "")
                if p.returncode != 0 and not opts.tolerate_agent_errors:  # an error, and it stays down
                    self.outcome.fail(note + " (--tolerate-agent-errors to accept)", ends_run=False)
                else:
                    self.outcome.warnings.append(note + (" (tolerated: --tolerate-agent-errors)" if p.returncode else ""))
                print(note, flush=True)
            self._heal_due()
            if time.monotonic() - last_rss >= RSS_PERIOD_S:
                children.sample_rss()
                last_rss = time.monotonic()
            now = time.monotonic()
            if opts.quiet or now - last_print < (STATUS_PERIOD_S if tty else 5.0):
                continue
            last_print = now
            lines = monitor.status_lines()
            if tty:
                if drawn:
                    sys.stdout.write(f"\x1b[{drawn}F")
                sys.stdout.write("".join(f"\x1b[2K{line}\n" for line in lines))
                sys.stdout.flush()
                drawn = len(lines)
            else:
                print(" | ".join(lines[:2]), flush=True)
        if world.returncode:
            self.outcome.fail(f"the world exited with {exit_text(world.returncode)}: {children.last_line('world')}")
            return False
        return True

"""`truav-swarm up`: start and watch a swarm of OS processes, then summarise.

The supervisor starts a Zenoh router on loopback, optionally the recorder,
the world process and one process per UAV agent (all `python -m
truav.swarm.cli ...`, logs under <out>/logs/), watches the bus (liveliness,
step metrics, beacons) for a live status table, and at the end (or on
Ctrl-C, SIGTERM or SIGHUP) stops every process it started, by PID, and prints
a summary with control-plane figures; it also draws <out>/summary.png.  Killed
outright, it cannot: its children then notice it is gone and stop by
themselves (:mod:`truav.swarm.lifeline`).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from truav.bus import keys, schema
from truav.config import Config, to_toml
from truav.faults import load_plan
from truav.bus.inbox import Inbox
from truav.swarm.lifeline import child_env, signals_handled
from truav.swarm.fault_control import FaultController
from truav.bus.transport import Bus, make_config

PID_FILE = "pids.json"
SCENARIO_FILE = "scenario.toml"
STATUS_PERIOD_S = 1.0
ROUTER_START_TIMEOUT_S = 15.0
STOP_TIMEOUT_S = 5.0
RECORDER_STOP_TIMEOUT_S = 60.0
"""The recorder finishes its file, then rewrites it into big chunks (seconds per 10 MB)."""
CENTRAL_STATE_VALUES = 50
"""The paper's centralized baseline: each UAV uploads a 50-value state at 10 Hz."""
CENTRAL_VALUE_BYTES = 4


@dataclass
class SwarmOptions:
    run: str = "demo"
    seed: int = 0
    episodes: int = 2
    lockstep: bool = False
    rate_hz: float = 10.0
    record: str | None = None
    qtable: str | None = None
    greedy: bool = False
    out: str | None = None
    listen: str | None = None
    plot: bool = True
    quiet: bool = False
    wait_agents_s: float = 60.0
    checkpoint_every: int = 50
    """Agents checkpoint their Q-table every this many steps."""
    verbose: bool = False
    """Children log at INFO level (joins, losses, checkpoint resumes) to <out>/logs."""
    fault_plan: str | None = None
    """Fault plan TOML (truav.faults): link faults applied by every process,
    crashes and freezes sent by this supervisor."""
    foxglove_port: int | None = None
    """Serve the run to the Foxglove app on ws://127.0.0.1:<port> (`truav-swarm view`)."""
    geo_origin: tuple[float, float] | None = None
    """(lat, lon) of the area's centre on Foxglove's map (recorder and view); None: Paris."""


def free_loopback_endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def wait_for_port(endpoint: str, timeout: float) -> bool:
    host, port = endpoint.split("/", 1)[1].rsplit(":", 1)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            with socket.create_connection((host, int(port)), timeout=0.5):
                return True
        except OSError:
            time.sleep(0.1)
    return False


class Children:
    """Processes this supervisor started; only these are ever signalled."""

    def __init__(self, log_dir: Path):
        self.log_dir = log_dir
        self.procs: dict[str, subprocess.Popen] = {}
        self.argv: dict[str, list[str]] = {}
        self._logs: list = []

    def start(self, name: str, argv: list[str]) -> subprocess.Popen:
        log = open(self.log_dir / f"{name}.log", "ab")  # a restarted process appends
        self._logs.append(log)
        proc = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                start_new_session=True,  # Ctrl-C reaches the supervisor only...
                                env=child_env())  # ...and each child stops if the supervisor dies (truav.swarm.lifeline)
        self.procs[name] = proc
        self.argv[name] = argv
        return proc

    def send(self, name: str, sig) -> None:
        p = self.procs.get(name)
        if p is not None and p.poll() is None:
            p.send_signal(sig)
            if sig == signal.SIGKILL:
                p.wait(timeout=5)

    def restart(self, name: str) -> None:
        p = self.procs.get(name)
        if p is not None and p.poll() is None:
            return
        self.start(name, self.argv[name])

    def stop(self, names: list[str], sig=signal.SIGTERM, timeout: float = STOP_TIMEOUT_S) -> None:
        live = [self.procs[n] for n in names if n in self.procs and self.procs[n].poll() is None]
        for p in live:
            p.send_signal(sig)
        deadline = time.monotonic() + timeout
        for p in live:
            try:
                p.wait(max(deadline - time.monotonic(), 0.01))
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()

    def stop_all(self) -> None:
        self.stop(list(self.procs))
        for f in self._logs:
            f.close()

    def pids(self) -> dict[str, int]:
        return {n: p.pid for n, p in self.procs.items()}


def stop_recorded_pids(out: Path) -> int:
    """SIGTERM the processes listed in <out>/pids.json that still run a TRUAV command."""
    path = out / PID_FILE
    if not path.is_file():
        return 0
    count = 0
    for pid in json.loads(path.read_text()).values():
        try:
            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
        except OSError:
            continue
        if b"truav.swarm.cli" in cmdline or b"recorder.process" in cmdline:
            os.kill(pid, signal.SIGTERM)
            count += 1
    return count


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
    lock: threading.Lock = field(default_factory=threading.Lock)
    beacon_inbox: Inbox | None = None

    def attach(self, bus: Bus, run: str) -> None:
        bus.subscribe(keys.metrics_step(run), self._on_step)
        bus.subscribe(keys.metrics_episode(run), self._on_episode)
        # Beacons are the bulk of the traffic: an inbox drained by poll() keeps this
        # process from being a 21st subscriber callback in every beacon's fan-out.
        self.beacon_inbox = bus.inbox(keys.all_beacons(run))
        bus.subscribe(keys.world_positions(run), self._on_positions)
        bus.subscribe(keys.world_tick(run), self._on_tick)
        bus.watch_liveliness(keys.all_alive(run), lambda k: self._live(k, True), lambda k: self._live(k, False))

    def _live(self, key: str, up: bool) -> None:
        with self.lock:
            (self.alive.add if up else self.alive.discard)(key.split("/alive/", 1)[-1])

    def _on_step(self, key, msg: schema.Metrics, raw, recv_ns) -> None:
        v = msg.values
        with self.lock:
            self.ticks.append((time.monotonic(), msg.tick))
            self.coverage.append((msg.tick, v.get("coverage_pct", 0.0)))
            self.hovering.append((msg.tick, v.get("hovering_uavs", 0.0)))
            self.generated += v.get("generated", 0.0)
            self.delivered += v.get("delivered", 0.0)
            self.energy.append(v.get("energy_j", 0.0))

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
        with self.lock:
            for r in heard:
                msg: schema.Beacon = r.msg
                self.beacon_count[msg.uav] += 1
                self.beacon_bytes[msg.uav] += len(r.raw)
                self.tracks[msg.uav].append(msg.pos)
                self.first_beacon = self.first_beacon or r.recv_ns / 1e9
                self.last_beacon = r.recv_ns / 1e9

    def _on_positions(self, key, msg: schema.Positions, raw, recv_ns) -> None:
        with self.lock:
            self.vehicles = list(msg.vehicles)

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
                f"coverage {cov:5.1f}%  PDR so far {pdr:6.3f}  energy/UAV/step {energy:6.1f} J",
                "alive: " + (" ".join(a.split("/")[1] for a in agents) or "-")]

    def control_plane(self) -> dict[str, float]:
        self.poll()
        with self.lock:
            n = sum(self.beacon_count.values())
            size = sum(self.beacon_bytes.values())
            span = (self.last_beacon - self.first_beacon) if n > 1 else float("nan")
            uavs = max(len(self.beacon_count), 1)
        per_s = n / span if span and span > 0 else float("nan")
        return {"beacons": n, "bytes_per_beacon": size / n if n else float("nan"),
                "beacons_per_s_total": per_s, "beacons_per_s_per_uav": per_s / uavs,
                "beacon_bytes_per_s_total": size / span if span and span > 0 else float("nan")}


def _python_module(*args: str) -> list[str]:
    return [sys.executable, "-m", *args]


def run_swarm(cfg: Config, opts: SwarmOptions) -> int:
    """Run a swarm to its end (or Ctrl-C, SIGTERM, SIGHUP), stop every process it started, summarise.

    Returns the exit code: 0, 130 if interrupted, 1-2 if it could not start."""
    with _terminate_as_interrupt():
        return _run_swarm(cfg, opts)


@contextlib.contextmanager
def _terminate_as_interrupt():
    """SIGTERM and SIGHUP stop the swarm as Ctrl-C does (main thread only), once: a second
    signal does not cut the shutdown short."""
    fired: list[int] = []

    def handler(signum: int, _frame: object) -> None:
        if not fired:
            fired.append(signum)
            raise KeyboardInterrupt

    with signals_handled((signal.SIGTERM, signal.SIGHUP), handler):
        yield


def _run_swarm(cfg: Config, opts: SwarmOptions) -> int:
    out = Path(opts.out or f"runs/swarm-{opts.run}")
    if opts.record and Path(opts.record).exists():
        print(f"truav-swarm: error: {opts.record} exists; choose another --record file (nothing was started)",
              file=sys.stderr)
        return 2
    (out / "logs").mkdir(parents=True, exist_ok=True)
    scenario = out / SCENARIO_FILE
    scenario.write_text(to_toml(cfg))
    endpoint = opts.listen or free_loopback_endpoint()
    n = cfg.scenario.n_uavs
    common = ["--run", opts.run, "--seed", str(opts.seed), "--scenario", str(scenario), "-e", endpoint]
    timing = (["--lockstep"] if opts.lockstep else []) + (["-v"] if opts.verbose else [])
    children = Children(out / "logs")
    monitor = Monitor(n, period_s=1.0 / opts.rate_hz)
    plan = load_plan(opts.fault_plan) if opts.fault_plan else None
    faults_args = ["--fault-plan", str(Path(opts.fault_plan).resolve())] if plan else []
    controller = None
    interrupted = False
    t0 = time.monotonic()
    try:
        children.start("router", _python_module("truav.swarm.cli", "router", "-l", endpoint))
        if not wait_for_port(endpoint, ROUTER_START_TIMEOUT_S):
            print(f"truav-swarm: error: the router did not open {endpoint} (see {out}/logs/router.log)", file=sys.stderr)
            return 1
        origin = ["--geo-origin", "%r,%r" % opts.geo_origin] if opts.geo_origin else []
        if opts.record:
            children.start("recorder", _python_module("recorder.process", "--run", opts.run, "--out", opts.record,
                                                        "--connect", endpoint, "--config-toml", str(scenario), *origin))
        if opts.foxglove_port is not None:
            children.start("view", _python_module("truav.swarm.cli", "view", *common, *origin,
                                                    "--port", str(opts.foxglove_port)))
        with Bus(keys.SRC_FAULT, opts.run, make_config(connect=[endpoint], connect_timeout_ms=5000)) as bus:
            monitor.attach(bus, opts.run)
            if opts.record:
                from recorder.process import wait_until_recording
                if not wait_until_recording(bus, opts.run, timeout=30.0):
                    print(f"truav-swarm: error: the recorder did not start (see {out}/logs/recorder.log)",
                          file=sys.stderr)
                    return 1
            if plan:
                hooks = {"kill": lambda u: children.send(f"agent{u}", signal.SIGKILL),
                         "restart": lambda u: children.restart(f"agent{u}"),
                         "freeze": lambda u: children.send(f"agent{u}", signal.SIGSTOP),
                         "thaw": lambda u: children.send(f"agent{u}", signal.SIGCONT)}
                controller = FaultController(bus, opts.run, plan, hooks)
            children.start("world", _python_module(
                "truav.swarm.cli", "world", *common, *timing, *faults_args, "--episodes", str(opts.episodes),
                "--rate", str(opts.rate_hz), "--stats-out", str(out / "world.json"),
                "--wait-agents", str(opts.wait_agents_s)))
            for i in range(n):
                extra = ["--checkpoint", str(out / f"agent{i}.npz"), "--stats-out", str(out / f"agent{i}.json"),
                         "--checkpoint-every", str(opts.checkpoint_every)]
                if opts.qtable:
                    extra += ["--qtable", opts.qtable]
                if opts.greedy:
                    extra += ["--greedy"]
                children.start(f"agent{i}", _python_module("truav.swarm.cli", "agent", "--id", str(i),
                                                            *common, *timing, *faults_args, "--rate",
                                                            str(opts.rate_hz), *extra))
            (out / PID_FILE).write_text(json.dumps(children.pids()))
            print(f"swarm '{opts.run}': router {endpoint}, world + {n} agents"
                  f"{' + recorder -> ' + opts.record if opts.record else ''}; "
                  f"{'lock-step' if opts.lockstep else f'{opts.rate_hz:g} Hz'}; logs in {out}/logs", flush=True)
            if opts.foxglove_port is not None:
                print(f"Foxglove: open ws://127.0.0.1:{opts.foxglove_port} (layout deploy/foxglove-layout.json)",
                      flush=True)
            _watch(children, monitor, opts, controller)
            monitor.poll()
            if controller is not None:
                controller.stop()
            children.stop([f"agent{i}" for i in range(n)], sig=signal.SIGCONT, timeout=0.01)  # thaw frozen ones
            children.stop([f"agent{i}" for i in range(n)])
    except KeyboardInterrupt:
        interrupted = True
        print("\ninterrupted: stopping every process of the swarm", flush=True)
    finally:
        children.stop([name for name in children.procs if name not in ("router", "recorder")])
        children.stop(["recorder"], sig=signal.SIGINT, timeout=RECORDER_STOP_TIMEOUT_S)
        children.stop(["router"])
        children.stop_all()
    elapsed = time.monotonic() - t0
    _summary(out, cfg, opts, monitor, elapsed, interrupted, controller)
    return 130 if interrupted else 0


def _watch(children: Children, monitor: Monitor, opts: SwarmOptions, controller=None) -> None:
    tty = sys.stdout.isatty() and not opts.quiet
    drawn = 0
    last_print = 0.0
    world = children.procs["world"]
    reported_dead: set[int] = set()
    faults_started = False
    while world.poll() is None:
        time.sleep(0.05 if controller is not None and not faults_started else 0.2)
        monitor.poll()
        if controller is not None and not faults_started and monitor.t0 is not None:
            controller.start(monitor.t0)
            faults_started = True
        for name, p in children.procs.items():
            if p.poll() is not None and p.pid not in reported_dead and name != "world":
                reported_dead.add(p.pid)
                if p.returncode:  # a clean exit (code 0) after the world's shutdown is not news
                    print(f"{name} exited with code {p.returncode} (log: {children.log_dir / name}.log)", flush=True)
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
        print(f"world exited with code {world.returncode}", flush=True)


def _summary(out: Path, cfg: Config, opts: SwarmOptions, monitor: Monitor, elapsed: float, interrupted: bool,
             controller=None) -> None:
    world = _read_json(out / "world.json")
    agents = [_read_json(out / f"agent{i}.json") for i in range(cfg.scenario.n_uavs)]
    print(f"\n== swarm '{opts.run}' summary ({elapsed:.1f} s{', interrupted' if interrupted else ''}) ==")
    episodes = (world or {}).get("episodes") or monitor.episodes
    for e, m in enumerate(episodes):
        print(f"episode {e}: coverage {m.get('coverage_pct', float('nan')):5.1f}%  PDR {m.get('pdr', float('nan')):.3f}  "
              f"delay {m.get('delay_ms', float('nan')):6.1f} ms  energy/UAV {m.get('energy_j', float('nan')) / 1e3:6.2f} kJ")
    if world:
        lat = world.get("tick_lateness_ms")
        if lat:
            print(f"tick lateness p50 {lat['p50']:.2f} ms, p99 {lat['p99']:.2f} ms over {lat['n']} ticks")
        print(f"ticks {world['ticks']}, actions received {world['actions_received']}, "
              f"missed (hovered) {world['deadline_misses']}, agent losses seen {len(world['losses'])}")
    lat = [a["beacon_latency_ms"] for a in agents if a and a.get("beacon_latency_ms", {}).get("n")]
    if lat:
        print(f"beacon one-way latency: p50 {np.median([x['p50'] for x in lat]):.2f} ms, "
              f"p99 {np.max([x['p99'] for x in lat]):.2f} ms (worst agent)")
    cp = monitor.control_plane()
    if cp["beacons"]:
        n = cfg.scenario.n_uavs
        central = n * CENTRAL_STATE_VALUES * opts.rate_hz
        print(f"control plane: {cp['bytes_per_beacon']:.0f} B/beacon, {cp['beacons_per_s_per_uav']:.1f} beacons/s per UAV, "
              f"{cp['beacon_bytes_per_s_total'] / 1e3:.1f} kB/s in total; a centralized critic would upload "
              f"{n} x {CENTRAL_STATE_VALUES} values x {opts.rate_hz:g} Hz = {central:,.0f} values/s "
              f"({central * CENTRAL_VALUE_BYTES / 1e3:.1f} kB/s of float32) to one controller")
    events = controller.events if controller is not None else []
    for t, kind, phase in events:
        print(f"fault {kind} {phase} at {t:.1f} s")
    with monitor.lock:
        timeline = {"coverage": monitor.coverage, "hovering": monitor.hovering}
    (out / "summary.json").write_text(json.dumps({"world": world, "agents": agents, "control_plane": cp,
                                                  "elapsed_s": elapsed, "interrupted": interrupted,
                                                  "fault_events": events, "timeline": timeline}, indent=1))
    if opts.plot and monitor.tracks:
        from truav.swarm.plots import swarm_figure
        path = swarm_figure(cfg, monitor, out / "summary.png", title=f"swarm '{opts.run}'")
        print(f"picture: {path}")
    if opts.record:
        print(f"recording: {opts.record}")


def _read_json(path: Path):
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None

"""Recorder throughput *from the bus*: ``python bench/bench_recorder_bus.py [--quick]``.

Processes on loopback: a Zenoh router, the recorder (``python -m
recorder.process.recorder``, zstd, JSON mirrors on) and a publisher.  Cases:

* flood: the publisher puts N obs payloads (20 keys, ~200 B, congestion
  control BLOCK so Zenoh back-pressures instead of dropping) as fast as it
  can.  Reported: the publisher's put rate, the recorder's *sustained* rate
  (messages / span of their receive times in the file) and the loss
  (N - recorded).  The slower of the two bounds the figure.
* swarm: the 20-agent 10 Hz mix (per tick: tick, 20 x obs + beacon +
  action, positions, step metrics = 630 msgs/s) paced in real time: the
  recorder must lose nothing (sequence check of the file) and keep a small
  backlog.
* references, in this process, same publisher: the Bus raw subscription
  counting only (the intake ceiling of any Bus-based recorder), and a
  pull-based Zenoh subscriber (``zenoh.handlers.FifoChannel``) drained by
  one thread that writes McapLog (what a pull-based ``Bus`` receive API
  would allow; it uses ``Bus.session``, the documented escape hatch).

On a machine with few cores the three processes compete for CPU: read the
figures with the core count printed at the top.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Callable

import msgpack

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from recorder.check import check  # noqa: E402
from recorder.mcap_log import McapLog  # noqa: E402
from recorder.process.recorder import spawn_recorder, stop_recorder, wait_until_recording  # noqa: E402
from recorder.reader import iter_messages  # noqa: E402
from recorder_payloads import N_UAVS, SWARM_MSGS_PER_TICK, TARGET_MSGS_S, TICK_HZ, swarm_mix  # noqa: E402
from truav.bus import transport
from truav.swarm.supervisor import RECORDER_STOP_TIMEOUT_S  # noqa: E402
from truav.wire import keys  # noqa: E402

RUN = "benchbus"
READY_TIMEOUT_S = 20.0
QUIET_S = 0.5  # the recorder's file has not grown for this long: it has written everything it got
DRAIN_TIMEOUT_S = 60.0
T0 = 1_732_200_000_000_000_000


def free_endpoint() -> str:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def client(endpoint: str):
    return transport.make_config("client", connect=[endpoint], connect_timeout_ms=5000)


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}


# --- the publisher (a child process) -----------------------------------------------------------
def flood_payloads(n: int) -> list[tuple[str, bytes]]:
    out = []
    for i in range(n):
        uav = i % N_UAVS
        body = {"v": 1, "kind": "obs", "src": "world", "seq": i, "t": T0 + i, "tick": i // N_UAVS, "episode": 0,
                "uav": uav, "pos": [100.0 + uav, 200.0], "vehicles_in_range": 7, "queued_packets": 3, "relayed": 41,
                "covered": 9, "energy_j": 1234.5, "speed_max": 20.0, "done": False}
        out.append((keys.uav_obs(RUN, uav), msgpack.packb(body)))
    return out


def swarm_ticks(n_ticks: int) -> list[list[tuple[str, bytes]]]:
    """The mix of recorder_payloads.swarm_mix, keyed under this run, grouped per tick."""

    flat = [(k.replace("truav/bench/", f"truav/{RUN}/"), p) for k, p, _ in swarm_mix(n_ticks)]
    return [flat[i:i + SWARM_MSGS_PER_TICK] for i in range(0, len(flat), SWARM_MSGS_PER_TICK)]


def publish_main(endpoint: str, mode: str, n: int, seconds: float) -> None:
    """Wait for a recorder token, publish, print one JSON line with what was sent."""
    with transport.Bus("world", RUN, client(endpoint)) as bus:
        if not wait_until_recording(bus, RUN, READY_TIMEOUT_S):
            raise SystemExit("publisher: no recorder appeared")
        if mode == "flood":
            batch = flood_payloads(n)
            start = time.perf_counter()
            for key, payload in batch:
                bus.publish_raw(key, payload)
            took = time.perf_counter() - start
            print(json.dumps({"sent": len(batch), "put_rate": len(batch) / took}), flush=True)
        else:
            ticks = swarm_ticks(int(seconds * TICK_HZ))
            start, sent = time.monotonic(), 0
            for i, tick in enumerate(ticks):
                for key, payload in tick:
                    bus.publish_raw(key, payload)
                sent += len(tick)
                time.sleep(max(start + (i + 1) / TICK_HZ - time.monotonic(), 0.0))
            print(json.dumps({"sent": sent, "put_rate": sent / (time.monotonic() - start)}), flush=True)
        time.sleep(0.5)  # let Zenoh flush before the session closes


def run_publisher(endpoint: str, mode: str, n: int, seconds: float) -> dict:
    proc = subprocess.Popen([sys.executable, __file__, "--publish", endpoint, mode, str(n), str(seconds)],
                            env=_env(), stdout=subprocess.PIPE, stdin=subprocess.DEVNULL)
    try:
        out, _ = proc.communicate(timeout=600)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    if proc.returncode:
        raise RuntimeError(f"publisher failed with code {proc.returncode}")
    return json.loads(out.decode().strip().splitlines()[-1])


# --- cases -------------------------------------------------------------------------------------------
def wait_quiet(path: Path) -> None:
    """Until the file has not grown for QUIET_S (the recorder flushes every 50 ms while it has data)."""
    deadline = time.monotonic() + DRAIN_TIMEOUT_S
    size, since = -1, time.monotonic()
    while time.monotonic() < deadline:
        now_size = path.stat().st_size if path.exists() else 0
        if now_size != size:
            size, since = now_size, time.monotonic()
        elif time.monotonic() - since >= QUIET_S:
            return
        time.sleep(0.05)


def recorder_case(endpoint: str, tmp: Path, mode: str, n: int, seconds: float) -> dict:
    out, summary = tmp / f"{mode}.mcap", tmp / f"{mode}.json"
    rec = spawn_recorder(RUN, out, [endpoint], force=True, extra=["--summary-json", str(summary)], env=_env(),
                         stdout=subprocess.DEVNULL)
    try:
        pub = run_publisher(endpoint, mode, n, seconds)
        wait_quiet(out)
    finally:
        # The recorder's finish (its backlog, the footer, the compaction) gets what `truav-swarm up` gives it.
        print(f"{'':52} stopping the recorder (SIGTERM; it has up to {RECORDER_STOP_TIMEOUT_S:.0f} s to finish "
              f"{out.name}, as under `truav-swarm up`)", flush=True)
        started = time.monotonic()
        code = stop_recorder(rec, timeout=RECORDER_STOP_TIMEOUT_S)
        print(f"{'':52} the recorder " + (f"finished in {time.monotonic() - started:.1f} s" if code == 0 else
              f"ended with {code} after {time.monotonic() - started:.1f} s"), flush=True)
    if code == -signal.SIGKILL:
        raise SystemExit(f"bench: the recorder did not finish {out.name} within {RECORDER_STOP_TIMEOUT_S:.0f} s "
                         "and was killed")
    if code != 0:
        raise SystemExit(f"bench: the recorder exited with {code} (see its stderr above)")
    times = [m.log_time for m in iter_messages(out)]
    span = (times[-1] - times[0]) / 1e9 if len(times) > 1 else float("nan")
    data = json.loads(summary.read_text())
    audit = check(out)
    return {**pub, "recorded": len(times), "rate": (len(times) - 1) / span if span else float("nan"),
            "lost": pub["sent"] - len(times), "missing_by_seq": audit.missing, "max_backlog": data["max_backlog"],
            "recorder_dropped": data["recorder_dropped"], "bytes": out.stat().st_size}


def in_process_case(endpoint: str, tmp: Path, n: int, attach: Callable[[transport.Bus, list], None]) -> dict:
    """Run ``attach(bus, stamps)`` (which subscribes), publish a flood from a child process, and measure
    the span of the stamps (perf_counter at each message handled)."""
    stamps: list[float] = []
    with transport.Bus("recorder", RUN, client(endpoint)) as bus:
        attach(bus, stamps)
        bus.declare_liveliness(keys.alive_recorder(RUN))
        pub = run_publisher(endpoint, "flood", n, 0.0)
        deadline = time.monotonic() + DRAIN_TIMEOUT_S
        while len(stamps) < pub["sent"] and time.monotonic() < deadline:
            before = len(stamps)
            time.sleep(QUIET_S)
            if len(stamps) == before:
                break
    got = len(stamps)
    span = stamps[-1] - stamps[0] if got > 1 else float("nan")
    return {**pub, "recorded": got, "rate": (got - 1) / span if span else float("nan"), "lost": pub["sent"] - got}


def attach_bus_count(bus: transport.Bus, stamps: list) -> None:
    bus.subscribe_raw(keys.everything(RUN), lambda k, raw, t: stamps.append(time.perf_counter()))


def make_attach_pull_writer(path: Path) -> Callable[[transport.Bus, list], None]:
    def attach(bus: transport.Bus, stamps: list) -> None:
        import zenoh  # only the reference touches zenoh directly, through Bus.session

        sub = bus.session.declare_subscriber(keys.everything(RUN), zenoh.handlers.FifoChannel(100_000))
        log = McapLog(path)

        def loop() -> None:
            clock, idle = time.time_ns, 0.0
            while idle < DRAIN_TIMEOUT_S:
                sample = sub.try_recv()
                if sample is None:
                    log.maybe_flush()
                    time.sleep(0.001)
                    idle += 0.001
                    continue
                idle = 0.0
                log.write(str(sample.key_expr), sample.payload.to_bytes(), clock())
                stamps.append(time.perf_counter())
                if len(stamps) >= FLOOD_N[0]:
                    break
            log.close()

        threading.Thread(target=loop, daemon=True).start()

    return attach


FLOOD_N = [0]  # the pull reference stops after this many messages (set by main)


def fmt(name: str, r: dict, target: float) -> str:
    return (f"{name:52} put {r['put_rate']:9,.0f}/s  recorded {r['recorded']:8,} of {r['sent']:8,}  "
            f"{r['rate']:9,.0f} msgs/s  ({r['rate'] / target:4.2f}x target)  lost {r['lost']}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="fewer messages, shorter swarm")
    parser.add_argument("--publish", nargs=4, metavar=("ENDPOINT", "MODE", "N", "SECONDS"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.publish:
        endpoint, mode, n, seconds = args.publish
        publish_main(endpoint, mode, int(n), float(seconds))
        return
    n = 50_000 if args.quick else 200_000
    swarm_s = 5.0 if args.quick else 20.0
    FLOOD_N[0] = n
    endpoint = free_endpoint()
    print(f"{os.cpu_count()} CPU cores; router, recorder and publisher are separate processes on loopback")
    serve = f"from truav.bus import transport; transport.run_router([{endpoint!r}])"
    router = subprocess.Popen([sys.executable, "-c", serve], env=_env(), stdin=subprocess.DEVNULL)
    try:
        time.sleep(1.0)
        with tempfile.TemporaryDirectory() as tmp_name:
            tmp = Path(tmp_name)
            flood = recorder_case(endpoint, tmp, "flood", n, 0.0)
            print(fmt("recorder process (Bus.receive_raw pull -> writer)", flood, TARGET_MSGS_S))
            print(f"{'':52} peak backlog {flood['max_backlog']:,}, dropped in the recorder "
                  f"{flood['recorder_dropped']}, file {flood['bytes']:,} bytes")
            swarm = recorder_case(endpoint, tmp, "swarm", 0, swarm_s)
            need = SWARM_MSGS_PER_TICK * TICK_HZ
            print(f"{'20-agent 10 Hz swarm mix, ' + f'{swarm_s:g} s paced':52} put {swarm['put_rate']:9,.0f}/s  "
                  f"recorded {swarm['recorded']:8,} of {swarm['sent']:8,}  lost {swarm['lost']}, missing by seq "
                  f"{swarm['missing_by_seq']}, peak backlog {swarm['max_backlog']} (needs {need} msgs/s: "
                  f"{flood['rate'] / need:,.0f}x headroom)")
            bus_only = in_process_case(endpoint, tmp, n, attach_bus_count)
            print(fmt("reference: Bus.subscribe_raw, counting only", bus_only, TARGET_MSGS_S))
            pull = in_process_case(endpoint, tmp, n, make_attach_pull_writer(tmp / "pull.mcap"))
            print(fmt("reference: zenoh FifoChannel pull + McapLog, 1 thread", pull, TARGET_MSGS_S))
    finally:
        router.send_signal(signal.SIGINT)
        try:
            router.wait(10)
        except subprocess.TimeoutExpired:
            router.kill()
            router.wait()


if __name__ == "__main__":
    main()

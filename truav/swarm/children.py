"""The processes `truav-swarm up` starts, and the endpoint its router listens on.

Only processes started here are ever signalled, by PID.  Each child's output
goes to <out>/logs/<name>.log; :meth:`Children.last_line` gives the line a
failed child ended with (its one-line error), for the console.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import time
from pathlib import Path

from truav.atomic import EXIT_NO_SPACE, write_kept
from truav.bus.transport import DEFAULT_ENDPOINT
from truav.lifecycle import child_env
from truav import jsonio

ROUTER_READY_LINE = b"router listening on"
"""What `truav-swarm router` prints once its endpoints are open."""


class ListenError(ValueError):
    """-l names an endpoint this host cannot listen on (a user mistake: one line, exit 2)."""


def _tcp_host_port(endpoint: str) -> tuple[str, int] | None:
    proto, _, address = endpoint.partition("/")
    host, _, port = address.split("#")[0].rpartition(":")
    if proto not in ("tcp", "tls") or not port.isdigit():
        return None
    return host.strip("[]"), int(port)


def _can_listen(host: str, port: int) -> OSError | None:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the router does: TIME_WAIT is no obstacle
        try:
            s.bind((host, port))
        except OSError as exc:
            return exc
    return None


def check_listen(endpoint: str) -> None:
    """Raise ListenError if ``endpoint`` (tcp/HOST:PORT) cannot be listened on here; others are left to Zenoh."""
    hp = _tcp_host_port(endpoint)
    if hp is None:
        return
    err = _can_listen(*hp)
    if err is not None:
        raise ListenError(f"-l {endpoint}: cannot listen there ({err.strerror or err}); "
                          f"choose another endpoint, or stop what uses it")


def free_loopback_endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def default_endpoint() -> str:
    """:data:`DEFAULT_ENDPOINT` (tcp/127.0.0.1:7447, where `status` and `down` look) if free, else a free port."""
    hp = _tcp_host_port(DEFAULT_ENDPOINT)
    return DEFAULT_ENDPOINT if hp and _can_listen(*hp) is None else free_loopback_endpoint()


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

    node_losses: tuple = ()
    """The cluster nodes lost mid-run (truav.swarm.ray_recovery.NodeLoss, under --ray); none on one host."""

    def __init__(self, log_dir: Path, pid_file: Path | None = None, on_start=None):
        self.log_dir = log_dir
        self.pid_file = pid_file
        self.on_start = on_start  # (name, Popen) -> None
        self.procs: dict[str, subprocess.Popen] = {}
        self.argv: dict[str, list[str]] = {}
        self.starts: dict[str, int] = {}  # name -> times started (a restarted process: its incarnations)
        self.started_at: dict[str, float] = {}
        self._log_offset: dict[str, int] = {}
        self._logs: list = []
        self.incarnations: list[tuple[str, subprocess.Popen, float]] = []  # every process started, in order
        self._rss: dict[int, list[int]] = {}  # pid -> [first kB sampled after RSS_SETTLE_S, max kB]

    def start(self, name: str, argv: list[str]) -> subprocess.Popen:
        path = self.log_dir / f"{name}.log"
        self._log_offset[name] = path.stat().st_size if path.exists() else 0  # a restarted process appends
        proc = self._spawn(name, argv, path)
        self.procs[name] = proc
        self.argv[name] = argv
        self.starts[name] = self.starts.get(name, 0) + 1
        self.started_at[name] = time.monotonic()
        self.incarnations.append((name, proc, self.started_at[name]))
        if self.pid_file is not None:
            text = jsonio.dumps(self.pids()).encode()  # whole or not at all: `down` and tests read it
            write_kept(self.pid_file, lambda f: f.write(text), lambda line: print(f"warning: {line}", flush=True))
        if self.on_start is not None:
            self.on_start(name, proc)
        return proc

    def _spawn(self, name: str, argv: list[str], log_path: Path):
        """Start ``name`` here; a subclass starts it elsewhere (truav.swarm.ray_swarm: on a Ray node) and
        returns an object with Popen's pid, returncode, poll, wait, send_signal and kill."""
        log = open(log_path, "ab")
        self._logs.append(log)
        return subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                start_new_session=True,  # Ctrl-C reaches the supervisor only...
                                env=child_env())  # ...and each child stops if the supervisor dies (truav.lifecycle)

    def log_text(self, name: str) -> bytes:
        """What the current process of ``name`` has written to its log so far."""
        try:
            with open(self.log_dir / f"{name}.log", "rb") as f:
                f.seek(self._log_offset.get(name, 0))
                return f.read()
        except OSError:
            return b""

    def last_line(self, name: str) -> str:
        lines = [ln for ln in self.log_text(name).decode(errors="replace").splitlines() if ln.strip()]
        return lines[-1].strip() if lines else "(its log is empty)"

    def alive(self, name: str) -> bool:
        p = self.procs.get(name)
        return p is not None and p.poll() is None

    def send(self, name: str, sig) -> None:
        p = self.procs.get(name)
        if p is not None and p.poll() is None:
            p.send_signal(sig)
            if sig == signal.SIGKILL:
                p.wait(timeout=5)

    def restart(self, name: str) -> None:
        if not self.alive(name):
            self.start(name, self.argv[name])

    def thaw(self, names: list[str]) -> None:
        """SIGCONT: a frozen (SIGSTOPped) process must run to stop cleanly; a running one ignores it."""
        for name in names:
            self.send(name, signal.SIGCONT)

    def wait_exit(self, names: list[str], timeout: float) -> list[str]:
        """Wait up to ``timeout`` for these processes to exit by themselves; the names still running."""
        deadline = time.monotonic() + timeout
        for name in names:
            p = self.procs.get(name)
            if p is None:
                continue
            try:
                p.wait(max(deadline - time.monotonic(), 0.0))
            except subprocess.TimeoutExpired:
                pass
        return [n for n in names if self.alive(n)]

    def stop(self, names: list[str], sig=signal.SIGTERM, timeout: float = 10.0) -> list[str]:
        """``sig`` to those still running, then SIGKILL any still running ``timeout`` later; the names killed."""
        live = [n for n in names if self.alive(n)]
        for n in live:
            self.procs[n].send_signal(sig)
        left = self.wait_exit(live, timeout)
        for n in left:
            self.procs[n].kill()
            self.procs[n].wait()
        return left

    def sample_rss(self) -> None:
        """Note the resident memory of every live process (for the memory-growth check of a soak)."""
        now = time.monotonic()
        for _, proc, started in self.incarnations:
            if proc.poll() is None and now - started >= RSS_SETTLE_S:
                kb = rss_kb(proc.pid)
                if kb is not None:
                    first_max = self._rss.setdefault(proc.pid, [kb, kb])
                    first_max[1] = max(first_max[1], kb)

    def incarnation_stats(self, t0: float) -> list[dict]:
        """Every process started: name, PID, start (s since ``t0``), exit code (None: still running), and
        its resident memory when first sampled and at most (MB), for summary.json."""
        out = []
        for name, proc, started in self.incarnations:
            rss = self._rss.get(proc.pid)
            out.append({"name": name, "pid": proc.pid, "started_s": round(started - t0, 2),
                        "exit_code": proc.poll(),
                        "rss_first_mb": round(rss[0] / 1024, 1) if rss else None,
                        "rss_max_mb": round(rss[1] / 1024, 1) if rss else None})
        return out

    def close_logs(self) -> None:
        for f in self._logs:
            f.close()
        self._logs = []

    def pids(self) -> dict[str, int]:
        return {n: p.pid for n, p in self.procs.items()}


RSS_SETTLE_S = 10.0
"""A process's memory is first sampled this long after its start (imports, JIT compilation and
first allocations are done by then), so growth is measured from a settled process."""


def rss_kb(pid: int) -> int | None:
    """VmRSS of a process in kB (Linux /proc), or None."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        pass
    return None


def exit_text(code: int | None) -> str:
    """How a process ended, for people: "killed by SIGKILL", "exit code 1"."""
    if code is not None and code < 0:
        with contextlib.suppress(ValueError):
            return f"killed by {signal.Signals(-code).name}"
    if code == EXIT_NO_SPACE:  # its own log line may not have fit on the full disk
        return f"exit code {code}: no space left on its disk"
    return f"exit code {code}"


def truav_process(pid: int) -> bool:
    """Whether ``pid`` runs a TRUAV swarm command (PIDs get reused: never signal another program)."""
    try:
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return False
    return b"truav.cli.swarm" in cmdline or b"recorder.process" in cmdline or b"truav.cli.log_process" in cmdline


def stop_recorded_pids(out: Path, wait_s: float = 0.0, pid_file: str = "pids.json") -> int:
    """Give the processes in <out>/pids.json ``wait_s`` seconds to exit, then SIGTERM those that still
    run a TRUAV command; returns how many were signalled."""
    path = out / pid_file
    if not path.is_file():
        return 0
    try:
        pids = [int(p) for p in json.loads(path.read_text()).values()]
    except (OSError, ValueError, TypeError, AttributeError):
        return 0
    deadline = time.monotonic() + wait_s
    while any(truav_process(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.2)
    count = 0
    for pid in pids:
        if truav_process(pid):
            try:
                os.kill(pid, signal.SIGTERM)
                count += 1
            except OSError:
                pass
    return count

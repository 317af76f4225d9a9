"""Hosts on one machine: network namespaces joined by veth pairs through a bridge.

    with Hosts.create({"a": "198.51.100.1", "b": "198.51.100.2"}) as hosts:
        proc = hosts.popen("a", [sys.executable, "-m", "truav.cli.swarm", "router", ...])
        hosts.cut("b")       # host b's cable out of the bridge (ip link set ... down)
        hosts.restore("b")

Each host is a namespace with loopback and one interface ``eth0`` holding its
address (a /24: the only route, no default route, so nothing leaves the
namespaces); the bridge lives in a namespace of its own, so nothing of the
test's network appears in the machine's own namespace.  Names carry a
per-run tag, and ``close()`` kills the processes it started (by PID) and
deletes every namespace it made, which takes their veths and the bridge
with them.  Needs root and ``ip`` (iproute2); :func:`unavailable` says why not.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import time
import uuid
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

PREFIX_LEN = 24
BRIDGE = "br0"
HOST_IF = "eth0"
STOP_GRACE_S = 15.0


def _ip(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    return subprocess.run(["ip", *args], capture_output=True, text=True, check=check, timeout=10)


def unavailable() -> str | None:
    """Why namespaces cannot be made here (not root, no ``ip``, no permission), or None."""
    if os.geteuid() != 0:
        return "needs root (network namespaces)"
    if shutil.which("ip") is None:
        return "needs iproute2's ip"
    probe = f"truav-probe-{uuid.uuid4().hex[:8]}"
    made = _ip("netns", "add", probe, check=False)
    if made.returncode != 0:
        return f"cannot create a network namespace: {made.stderr.strip()}"
    try:  # everything the hosts need: a veth pair, a bridge, running a program inside
        for what, argv in (("a veth pair", ["-n", probe, "link", "add", "v0", "type", "veth", "peer", "name", "v1"]),
                           ("a bridge", ["-n", probe, "link", "add", "br0", "type", "bridge"]),
                           ("ip netns exec", ["netns", "exec", probe, "true"])):
            got = _ip(*argv, check=False)
            if got.returncode != 0:
                return f"cannot make {what} in a namespace: {got.stderr.strip()}"
    finally:
        _ip("netns", "del", probe, check=False)
    return None


@dataclass
class Hosts:
    """Namespaces ``<tag>-<host>`` on a bridge in ``<tag>-sw``; made by :meth:`create`."""

    tag: str
    addresses: dict[str, str]
    namespaces: list[str] = field(default_factory=list)
    procs: list[subprocess.Popen] = field(default_factory=list)

    @classmethod
    def create(cls, addresses: Mapping[str, str]) -> "Hosts":
        hosts = cls(f"truav-{uuid.uuid4().hex[:6]}", dict(addresses))
        try:
            sw = hosts._add_ns("sw")
            _ip("-n", sw, "link", "add", BRIDGE, "type", "bridge")
            _ip("-n", sw, "link", "set", "dev", BRIDGE, "up")
            for name, address in hosts.addresses.items():
                ns = hosts._add_ns(name)
                port = hosts.port(name)
                # Both ends made straight inside their namespaces: the machine's own never sees them.
                _ip("link", "add", "name", port, "netns", sw, "type", "veth", "peer", "name", HOST_IF, "netns", ns)
                _ip("-n", sw, "link", "set", "dev", port, "master", BRIDGE)
                _ip("-n", sw, "link", "set", "dev", port, "up")
                _ip("-n", ns, "link", "set", "dev", "lo", "up")
                _ip("-n", ns, "addr", "add", f"{address}/{PREFIX_LEN}", "dev", HOST_IF)
                _ip("-n", ns, "link", "set", "dev", HOST_IF, "up")
        except BaseException:
            hosts.close()
            raise
        return hosts

    def _add_ns(self, name: str) -> str:
        ns = self.ns(name)
        _ip("netns", "add", ns)
        self.namespaces.append(ns)
        return ns

    def ns(self, host: str) -> str:
        return f"{self.tag}-{host}"

    @staticmethod
    def port(host: str) -> str:
        """The bridge-side end of ``host``'s cable (in the switch namespace)."""
        return f"port-{host}"

    def popen(self, host: str, argv: Sequence[str], **kwargs) -> subprocess.Popen:
        """Start ``argv`` inside ``host``'s namespace (``ip netns exec`` execs it: the PID is the program's)."""
        proc = subprocess.Popen(["ip", "netns", "exec", self.ns(host), *argv], **kwargs)
        self.procs.append(proc)
        return proc

    def run(self, host: str, argv: Sequence[str], timeout: float = 30.0) -> subprocess.CompletedProcess:
        return subprocess.run(["ip", "netns", "exec", self.ns(host), *argv], capture_output=True, text=True,
                              timeout=timeout)

    def cut(self, host: str) -> None:
        """Pull ``host``'s cable: its bridge port down, so it reaches no other host."""
        _ip("-n", self.ns("sw"), "link", "set", "dev", self.port(host), "down")

    def restore(self, host: str) -> None:
        _ip("-n", self.ns("sw"), "link", "set", "dev", self.port(host), "up")

    def stop(self, proc: subprocess.Popen, sig: int = signal.SIGTERM, grace_s: float = STOP_GRACE_S) -> int:
        """Signal one process this object started; SIGKILL after ``grace_s``; its exit code."""
        if proc.poll() is None:
            proc.send_signal(sig)
            try:
                proc.wait(timeout=grace_s)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10)
        return proc.returncode

    def close(self) -> None:
        """Stop every process started here (SIGTERM, SIGKILL after a grace), then delete every namespace made."""
        for proc in self.procs:
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + STOP_GRACE_S
        for proc in self.procs:
            try:
                proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10)
        for ns in reversed(self.namespaces):
            _ip("netns", "del", ns, check=False)
        self.namespaces.clear()

    def __enter__(self) -> "Hosts":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def leftovers(tag: str) -> list[str]:
    """Namespaces whose name starts with ``tag`` (none after close())."""
    out = _ip("netns", "list", check=False).stdout
    return [line.split()[0] for line in out.splitlines() if line.startswith(tag)]

"""A multi-host deployment: which host runs which router and components (``deploy/*.toml``).

    run = "demo"
    agents = 4
    port = 7447

    [[host]]
    name = "a"
    address = "198.51.100.1"
    runs = ["world", "recorder", "supervisor"]

    [[host]]
    name = "b"
    address = "198.51.100.2"
    runs = ["uav/0-1"]          # uav/0 and uav/1

`truav-swarm certs --deployment FILE --out DIR` issues one credentials bundle
per host from it (``DIR/<host>/``); `truav-swarm deploy-configs FILE --out DIR`
writes the same zenoh configs without any key (what ``deploy/three-hosts/``
holds).  Both go through :func:`truav.bus.security.site_configs`.
"""

from __future__ import annotations

import ipaddress
import re
from dataclasses import dataclass, fields
from pathlib import Path

from truav.bus import security
from truav.config import read_toml
from truav.errors import UserError
from truav.wire import keys

DEFAULT_PORT = 7447
_HOST_NAME = re.compile(r"^[a-z0-9][a-z0-9-]{0,30}$")
_LABEL = r"[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?"
_DNS_NAME = re.compile(rf"^(?=.{{1,253}}$){_LABEL}(\.{_LABEL})*$")
_UAV_RANGE = re.compile(r"^uav/(\d+)-(\d+)$")


class DeploymentError(UserError):
    """A mistake in a deployment file: the message names the file and the key."""


@dataclass(frozen=True)
class HostEntry:
    """One ``[[host]]`` table."""

    name: str
    """Short name (lower-case letters, digits, '-'): the bundle's directory and the router's identity router/<name>."""
    address: str
    """IP address or DNS name of the host: its router listens there and the other routers dial it."""
    runs: tuple[str, ...] = ()
    """Components started on this host: world, recorder, supervisor, view, replay, controller, uav/<i> or uav/<i>-<j>."""


@dataclass(frozen=True)
class Deployment:
    """A swarm spread over hosts, a router on each, every router linked to every other."""

    run: str
    """Run name: keys under truav/<run>/, and the run the access control is written for."""
    agents: int
    """Number of UAV agents (uav/0 .. uav/<agents-1>), each placed on exactly one host."""
    hosts: tuple[HostEntry, ...]
    """The hosts, in order: each router dials the routers of the hosts listed before it."""
    port: int = DEFAULT_PORT
    """TCP port of every router's TLS endpoint."""

    def sites(self) -> tuple[security.Site, ...]:
        return tuple(security.Site(h.name, h.address, self.port, h.runs) for h in self.hosts)

    def host_of(self, identity: str) -> HostEntry:
        return next(h for h in self.hosts if identity in h.runs)


def _known(where: str, table: dict, cls) -> None:
    unknown = set(table) - {f.name if f.name != "hosts" else "host" for f in fields(cls)}
    if unknown:
        raise DeploymentError(f"{where}: unknown key '{sorted(unknown)[0]}' "
                              f"(known: {', '.join(f.name if f.name != 'hosts' else 'host' for f in fields(cls))})")


def _expand(where: str, entry: str, agents: int) -> list[str]:
    m = _UAV_RANGE.match(entry)
    if m:
        lo, hi = int(m[1]), int(m[2])
        if lo > hi:
            raise DeploymentError(f"{where}: {entry!r} is an empty range")
        ids = [keys.uav_identity(i) for i in range(lo, hi + 1)]
    else:
        ids = [entry]
    for identity in ids:
        uav = keys.parse_uav_identity(identity)
        if uav is not None and uav >= agents:
            raise DeploymentError(f"{where}: {identity} is outside uav/0..uav/{agents - 1} (agents = {agents})")
        if uav is None and identity not in (security.WORLD, security.RECORDER, security.SUPERVISOR, security.VIEW,
                                            security.REPLAY, security.CONTROLLER):
            raise DeploymentError(f"{where}: unknown component {identity!r} (world, recorder, supervisor, view, "
                                  f"replay, controller, uav/<i> or uav/<i>-<j>)")
    return ids


def _check_address(where: str, address: object) -> str:
    if not isinstance(address, str):
        raise DeploymentError(f"{where}.address: must be a string, got {address!r}")
    try:
        ipaddress.ip_address(address)
    except ValueError:
        if not _DNS_NAME.match(address):
            raise DeploymentError(f"{where}.address {address!r}: neither an IP address nor a host name") from None
    return address


def from_dict(data: dict, source: str) -> Deployment:
    """A checked deployment; :class:`DeploymentError` names ``source`` and the key at fault."""
    _known(source, data, Deployment)
    for key in ("run", "agents", "host"):
        if key not in data:
            raise DeploymentError(f"{source}: missing key '{key}'")
    run = data["run"]
    try:
        keys.validate_run(run if isinstance(run, str) else "")
    except ValueError as exc:
        raise DeploymentError(f"{source}: run: {exc}") from None
    agents, port = data["agents"], data.get("port", DEFAULT_PORT)
    if not isinstance(agents, int) or isinstance(agents, bool) or agents < 1:
        raise DeploymentError(f"{source}: agents must be a positive integer, got {agents!r}")
    if not isinstance(port, int) or isinstance(port, bool) or not 1 <= port <= 65535:
        raise DeploymentError(f"{source}: port must be an integer in [1, 65535], got {port!r}")
    tables = data["host"]
    if not isinstance(tables, list) or not tables or not all(isinstance(t, dict) for t in tables):
        raise DeploymentError(f"{source}: host must be a list of [[host]] tables")
    hosts, placed = [], {}
    for n, t in enumerate(tables):
        where = f"{source}: host[{n}]"
        _known(where, t, HostEntry)
        name = t.get("name")
        if not isinstance(name, str) or not _HOST_NAME.match(name):
            raise DeploymentError(f"{where}.name: lower-case letters, digits and '-' (at most 31), got {name!r}")
        where = f"{source}: host {name!r}"
        if any(h.name == name for h in hosts):
            raise DeploymentError(f"{where}: listed twice")
        address = _check_address(where, t.get("address"))
        if any(h.address == address for h in hosts):
            raise DeploymentError(f"{where}.address {address}: already the address of another host")
        runs = t.get("runs", [])
        if not isinstance(runs, list) or not all(isinstance(r, str) for r in runs):
            raise DeploymentError(f"{where}.runs: must be a list of component names")
        ids = [i for r in runs for i in _expand(f"{where}.runs", r, agents)]
        for identity in ids:
            if identity in placed:
                raise DeploymentError(f"{where}.runs: {identity} is already placed on host {placed[identity]!r}")
            placed[identity] = name
        hosts.append(HostEntry(name, address, tuple(ids)))
    missing = [i for i in (security.WORLD, *(keys.uav_identity(u) for u in range(agents))) if i not in placed]
    if missing:
        raise DeploymentError(f"{source}: {missing[0]} runs on no host (every run needs the world and "
                              f"uav/0..uav/{agents - 1}; add it to some host's runs)")
    return Deployment(run, agents, tuple(hosts), port)


def load(path: str | Path, flag: str = "--deployment") -> Deployment:
    return from_dict(read_toml(path, flag, DeploymentError), f"{flag} {path}")

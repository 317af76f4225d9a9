"""The Zenoh config files of a secure swarm: the router's (mutual TLS, the ACL, the rate caps) and one
client config per component, for one host or one bundle per host of a deployment (:class:`Site`);
plus the credentials directory's file names and a probe telling a TLS router from a plain one."""

from __future__ import annotations

import base64
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from truav.bus.acl import ROUTER, CredentialsError, Grant, acl_config, file_stem, grants
from truav.bus.rate_caps import downsampling_config
from truav import jsonio

CA_CERT = "ca.pem"
CA_KEY = "ca.key"
ROUTER_CONFIG = "router.json5"
MANIFEST = "manifest.json"
DEFAULT_HOSTS = ("localhost", "127.0.0.1")


@dataclass(frozen=True)
class Site:
    """One host of a multi-host swarm: its router and the components started there."""

    name: str
    """Short host name: the bundle's directory and the router's identity ``router/<name>``."""
    address: str
    """IP address or DNS name the host's router listens on and the other routers dial."""
    port: int
    """TCP port of that router's TLS endpoint."""
    identities: tuple[str, ...] = ()
    """Components run on this host (``world``, ``recorder``, ``uav/<i>`` ...): their keys go only there."""

    @property
    def router(self) -> str:
        """The router's identity and certificate common name."""
        return f"{ROUTER}/{self.name}"

    @property
    def endpoint(self) -> str:
        host = f"[{self.address}]" if ":" in self.address else self.address  # IPv6 literal
        return f"tls/{host}:{self.port}"



TLS_FILE_KEYS = ("root_ca_certificate", "listen_private_key", "listen_certificate", "connect_private_key",
                 "connect_certificate")
"""The TLS settings that name files; a relative one is read next to its config file (zenoh_config.make_config)."""


INLINE_SUFFIX = "_base64"
"""Zenoh 1.x reads each TLS file setting also inline: ``<name>_base64``, the file's bytes (PEM) in base64."""


def inline_material(conf: dict, directory: Path) -> dict:
    """``conf`` with every TLS file it names (a relative name: in ``directory``) put inline
    (``root_ca_certificate`` -> ``root_ca_certificate_base64``, ...): the config then holds its certificates
    and key itself, and plain Zenoh (``zenoh.Config.from_file``, ``zenohd -c``) loads it from any working
    directory. It holds a private key: write it owner-only (:func:`_write_json` ``secret``)."""
    tls = conf.get("transport", {}).get("link", {}).get("tls", {})
    for name in TLS_FILE_KEYS:
        value = tls.pop(name, None)
        if value is not None:
            path = Path(value) if os.path.isabs(value) else directory / value
            tls[name + INLINE_SUFFIX] = base64.b64encode(path.read_bytes()).decode("ascii")
    return conf


def _file_namer(directory: Path | None):
    """Absolute paths into ``directory`` (one host's credentials, made where they are used), or bare
    file names (a bundle copied to another host: resolved against the config file's own directory)."""
    if directory is None:
        return lambda name: name
    d = directory.resolve()
    return lambda name: str(d / name)



def router_config(directory: Path | None, listen: Sequence[str], table: Sequence[Grant], *,
                  connect: Sequence[str] = (), peer_routers: Sequence[str] = (),
                  caps: Sequence[tuple[str, float]] = ()) -> dict:
    """The router's zenoh config: mutual TLS on ``listen``, the ACL of ``table``, the rate ``caps``
    (:func:`rate_caps`) if any; with ``connect``, it also dials those routers (mutual TLS, their names
    verified), and ``peer_routers`` relay."""
    f = _file_namer(directory)
    tls = {
        "root_ca_certificate": f(CA_CERT),
        "listen_private_key": f(f"{ROUTER}.key"),
        "listen_certificate": f(f"{ROUTER}.pem"),
        "enable_mtls": True,
        "close_link_on_expiration": True,
    }
    conf: dict = {"mode": "router", "listen": {"endpoints": list(listen)}}
    if connect:
        conf["connect"] = {"endpoints": list(connect)}
        tls.update({"connect_private_key": f(f"{ROUTER}.key"), "connect_certificate": f(f"{ROUTER}.pem"),
                    "verify_name_on_connect": True})
    conf.update({"scouting": {"multicast": {"enabled": False}}, "transport": {"link": {"tls": tls}},
                 "access_control": acl_config(table, peer_routers)})
    if caps:
        conf["downsampling"] = downsampling_config(caps)
    return conf


def client_config(directory: Path | None, identity: str, connect: Sequence[str]) -> dict:
    f, stem = _file_namer(directory), file_stem(identity)
    return {
        "mode": "client",
        "connect": {"endpoints": list(connect)},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"link": {"tls": {
            "root_ca_certificate": f(CA_CERT),
            "connect_private_key": f(f"{stem}.key"),
            "connect_certificate": f(f"{stem}.pem"),
            "enable_mtls": True,
            "verify_name_on_connect": True,
        }}},
    }


def site_configs(run: str, n_uavs: int, sites: Sequence[Site]) -> dict[str, dict[str, dict]]:
    """Per host, its config files by name: ``router.json5`` and one ``<identity>.json5`` per component
    placed there.  Router ``k`` dials routers ``0..k-1`` (one link per pair, a full mesh); each client
    connects to its own host's router.  File names are relative (the bundle can live anywhere), and
    nothing here is secret or random: ``truav-swarm deploy-configs`` writes exactly these."""
    table = grants(run, n_uavs)
    by_identity = {g.identity: g for g in table}
    routers = [site.router for site in sites]
    out: dict[str, dict[str, dict]] = {}
    for k, site in enumerate(sites):
        unknown = [i for i in site.identities if i not in by_identity]
        if unknown:
            raise CredentialsError(f"host {site.name}: no such identity {unknown[0]!r} "
                                   f"(known: {', '.join(list(by_identity)[:6])}, uav/0..uav/{n_uavs - 1})")
        files = {ROUTER_CONFIG: router_config(None, [site.endpoint], table,
                                              connect=[s.endpoint for s in sites[:k]],
                                              peer_routers=[r for r in routers if r != site.router])}
        for identity in site.identities:
            files[f"{file_stem(identity)}.json5"] = client_config(None, identity, [site.endpoint])
        out[site.name] = files
    return out


def site_manifest(run: str, n_uavs: int, sites: Sequence[Site], site: Site) -> dict:
    return {"run": run, "n_uavs": n_uavs, "endpoint": site.endpoint, "hosts": [site.address, *DEFAULT_HOSTS],
            "identities": list(site.identities), "site": site.name, "router": site.router,
            "peer_routers": [s.router for s in sites if s is not site]}


def write_configs(directory: Path, files: dict[str, dict], *, inline: bool = False) -> None:
    """Each config into ``directory``; ``inline``: with the TLS files it names (already there) inline,
    owner-only (:func:`inline_material`)."""
    directory.mkdir(parents=True, exist_ok=True)
    for name, conf in files.items():
        _write_json(directory / name, inline_material(conf, directory) if inline else conf, secret=inline)


def tls_endpoint(endpoint: str) -> str:
    """``tcp/HOST:PORT`` -> ``tls/HOST:PORT`` (a tls endpoint is kept)."""
    proto, sep, rest = endpoint.partition("/")
    if not sep or proto not in ("tcp", "tls"):
        raise CredentialsError(f"endpoint {endpoint!r}: --secure needs tcp/HOST:PORT or tls/HOST:PORT")
    return f"tls/{rest}"


TLS_PROBE = b"\x00\x10not a tls record"
"""Bytes that are no TLS record (content type 0): a TLS server answers them with an alert record."""


def answers_tls(endpoint: str, timeout_s: float = 1.0) -> bool:
    """Whether a TLS server listens at a ``tcp/`` or ``tls/`` HOST:PORT endpoint (a --secure swarm's
    router): it answers bytes that are no TLS record with a TLS alert (content type 21, version 3.x),
    where a plain Zenoh router just closes the link. False when nothing answers."""
    import socket
    proto, _, address = endpoint.partition("/")
    host, _, port = address.split("?")[0].split("#")[0].rpartition(":")
    if proto not in ("tcp", "tls") or not port.isdigit():
        return False
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s) as sock:
            sock.settimeout(timeout_s)
            sock.sendall(TLS_PROBE)
            reply = sock.recv(2)
    except OSError:
        return False
    return len(reply) == 2 and reply[0] == 0x15 and reply[1] == 0x03


def _write_json(path: Path, data: dict, *, secret: bool = False) -> None:
    """JSON (which is JSON5); ``secret``: owner-only (it holds a private key)."""
    text = jsonio.dumps(data, indent=1) + "\n"
    if not secret:
        path.write_text(text)
        return
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    os.chmod(path, 0o600)  # an older file of that name kept its mode
    with os.fdopen(fd, "w") as f:
        f.write(text)


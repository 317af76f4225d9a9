"""Security material for a locked bus: one CA, one certificate per component, the router's ACL.

Everything the router enforces comes from ONE table, :func:`grants`: for each
identity (``world``, ``uav/<i>``, ``recorder``, ``supervisor``, ``replay``, ``controller``)
the keys it may put, the key expressions it may subscribe to, the liveliness
tokens it may declare and the tokens it may watch.  From that table

* :func:`acl_config` writes Zenoh's ``access_control`` section (default deny;
  subjects are certificate common names, CN = identity);
* :func:`explain` tells which identity may put or subscribe where
  (``truav-swarm acl explain``);
* :func:`issue` (``truav-swarm up --secure`` / ``truav-swarm certs``) creates
  the CA and the certificates with the ``cryptography`` library and writes
  ``router.json5`` plus one ``<name>.json5`` client config per component into
  a credentials directory, so parts started by hand (``-c DIR/world.json5``
  or ``--creds DIR``) use the same material;
* with ``sites`` (a router per host, ``truav-swarm certs --deployment``),
  :func:`site_configs` writes each host's router config (listening on its
  address, dialling the routers listed before it, trusting them as relays)
  and its components' client configs; :func:`issue` puts them, with that
  host's keys only, into one bundle per host (``deploy/README.md``).

How Zenoh applies the table (zenoh 1.10, checked by ``tests/test_security.py``):
the router's ACL interceptor sees every message at *ingress* (from the client
that sent it) and *egress* (to each client it forwards to), with the sender's
or receiver's certificate CN as subject.  So a put needs ``put``/ingress on the
sender's side and ``put``/egress on each receiver's side; a subscription needs
``declare_subscriber``/ingress; a liveliness token ``liveliness_token``/ingress
for its owner and ``liveliness_token``/egress for its watchers; a liveliness
query ``liveliness_query``/ingress.  Anything not listed is denied.

Transport: TLS with mutual authentication (``enable_mtls``) against this CA
only; a client without a certificate, with one from another CA or with an
expired one fails the handshake and never gets a session.
"""

from __future__ import annotations

import datetime as dt
import fnmatch
import ipaddress
import json
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from truav.bus import keys

ROUTER = "router"
WORLD = keys.SRC_WORLD
RECORDER = keys.SRC_RECORDER
SUPERVISOR = "supervisor"
REPLAY = keys.SRC_REPLAY
CONTROLLER = keys.SRC_CONTROLLER  # the central scheme's controller (agents.central_process)
VIEW = "view"  # the Foxglove bridge (truav.swarm.view)

CA_CERT = "ca.pem"
CA_KEY = "ca.key"
ROUTER_CONFIG = "router.json5"
MANIFEST = "manifest.json"
DEFAULT_VALID_DAYS = 30
DEFAULT_HOSTS = ("localhost", "127.0.0.1")
REPLAY_RUN_SUFFIX = "-replay"


class CredentialsError(ValueError):
    """A credentials directory that is missing, incomplete or made for another run."""


# --- the one table -----------------------------------------------------------------------------
@dataclass(frozen=True)
class Grant:
    """What one identity may do on the bus (full key expressions)."""

    identity: str
    """The sender id and certificate common name: ``world``, ``uav/<i>``, ``recorder`` ..."""
    put: tuple[str, ...] = ()
    """Keys it may put on (and whose subscribers it may learn of)."""
    subscribe: tuple[str, ...] = ()
    """Key expressions it may subscribe to; the router forwards it only puts on these."""
    tokens: tuple[str, ...] = ()
    """Liveliness tokens it may declare."""
    watch: tuple[str, ...] = ()
    """Liveliness key expressions it may watch or query."""


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


def replay_run(run: str) -> str:
    """The run a replay publishes into under --secure: its own, next to the live one."""
    return keys.validate_run(run + REPLAY_RUN_SUFFIX)


def grants(run: str, n_uavs: int) -> tuple[Grant, ...]:
    """Who may put / subscribe where in run ``run`` with ``n_uavs`` agents (docs/security.md)."""
    p = keys.prefix(run)
    r = keys.prefix(replay_run(run))
    table = [
        Grant(WORLD,
              put=(f"{p}/world/*", keys.all_obs(run), keys.all_metrics(run),
                   # The world announces the end of the run: its only control key.
                   keys.control(run, "shutdown")),
              subscribe=(keys.all_actions(run), keys.all_control(run), keys.world_tick(run)),
              tokens=(keys.alive_world(run),), watch=(keys.all_alive_uavs(run), keys.alive_controller(run))),
        # Scheme central: every UAV's state upload in, one command per UAV out.
        Grant(CONTROLLER, put=(keys.all_commands(run),),
              subscribe=(keys.all_states(run), keys.all_control(run), keys.world_tick(run)),
              tokens=(keys.alive_controller(run),), watch=(keys.all_alive_uavs(run),)),
        Grant(RECORDER, subscribe=(keys.everything(run),), tokens=(keys.alive_recorder(run),),
              watch=(keys.all_alive(run),)),
        Grant(SUPERVISOR,
              put=(keys.all_control(run), keys.all_faults(run)),
              subscribe=(keys.all_metrics(run), f"{p}/world/*", keys.all_beacons(run), keys.all_beacons_in_cells(run),
                         keys.all_control(run), keys.all_states(run), keys.all_commands(run),  # traffic measured for the summary
                         keys.all_health(run)),  # the agents' health reports, for `status`
              watch=(keys.all_alive(run),)),
        Grant(VIEW, subscribe=(keys.everything(run),)),
        Grant(REPLAY, put=(f"{r}/**",), subscribe=(keys.control(replay_run(run), "replay"),),
              tokens=(), watch=()),
    ]
    for i in range(n_uavs):
        table.append(Grant(
            keys.uav_identity(i),
            put=(keys.uav_beacon(run, i), f"{keys.uav_beacon(run, i)}/*", keys.uav_action(run, i), keys.uav_state(run, i),
                 keys.uav_health(run, i)),
            subscribe=(keys.uav_obs(run, i), keys.all_beacons(run), keys.all_beacons_in_cells(run), keys.world_tick(run),
                       keys.all_control(run), keys.controller_cmd(run, i)),
            tokens=(keys.alive_uav(run, i),), watch=(keys.all_alive_uavs(run), keys.alive_controller(run))))
    return tuple(table)


def component_names(n_uavs: int) -> tuple[str, ...]:
    """File stems of the credentials: router, world, ..., uav-0, uav-1, ..."""
    return (ROUTER, WORLD, RECORDER, SUPERVISOR, VIEW, REPLAY, CONTROLLER, *(file_stem(keys.uav_identity(i)) for i in range(n_uavs)))


def file_stem(identity: str) -> str:
    """``uav/3`` -> ``uav-3`` (file names cannot hold a slash)."""
    return identity.replace("/", "-")


# --- Zenoh's access_control section -------------------------------------------------------------
def _rule(rid: str, messages: Sequence[str], flow: str, key_exprs: Iterable[str]) -> dict:
    return {"id": rid, "messages": list(messages), "flows": [flow], "permission": "allow",
            "key_exprs": sorted(set(key_exprs))}


ALL_MESSAGES = ("put", "delete", "declare_subscriber", "query", "declare_queryable", "reply", "liveliness_token",
                "declare_liveliness_subscriber", "liveliness_query")
PEER_ROUTERS = "peer-routers"


def acl_config(table: Sequence[Grant], peer_routers: Sequence[str] = ()) -> dict:
    """Zenoh ``access_control`` (default deny) that allows exactly what ``table`` says.

    ``peer_routers`` (certificate CNs of the other routers of a deployment) may relay
    everything of the table's runs both ways: the router a client connects to enforces
    that client's grant, so a put from ``uav/1`` on host B was checked by B's router
    before A's router sees it arrive from ``router/b``."""
    rules, subjects, policies = [], [], []
    for g in table:
        sid = file_stem(g.identity)
        subjects.append({"id": sid, "cert_common_names": [g.identity]})
        mine = []

        def add(kind: str, messages: Sequence[str], flow: str, exprs: Sequence[str]) -> None:
            if exprs:
                rules.append(_rule(f"{sid}-{kind}", messages, flow, exprs))
                mine.append(f"{sid}-{kind}")

        add("put", ("put", "delete"), "ingress", g.put)
        # A declared publisher sends only while the router has told it of a matching subscriber, and
        # a subscription such as uav/*/action is no key of uav/1's: it learns of every one in its run.
        add("put-matching", ("declare_subscriber",), "egress", sorted({_run_of(e) for e in g.put}))
        add("subscribe", ("declare_subscriber",), "ingress", g.subscribe)
        add("receive", ("put", "delete"), "egress", g.subscribe)
        add("token", ("liveliness_token",), "ingress", g.tokens)
        add("watch", ("declare_liveliness_subscriber", "liveliness_query"), "ingress", g.watch)
        add("watch-receive", ("liveliness_token", "reply"), "egress", g.watch)
        if mine:
            policies.append({"id": sid, "rules": mine, "subjects": [sid]})
    if peer_routers:
        spaces = sorted({_run_of(e) for g in table for e in (*g.put, *g.subscribe, *g.tokens, *g.watch)})
        subjects.append({"id": PEER_ROUTERS, "cert_common_names": sorted(peer_routers)})
        rules.append({"id": f"{PEER_ROUTERS}-relay", "messages": list(ALL_MESSAGES), "flows": ["ingress", "egress"],
                      "permission": "allow", "key_exprs": spaces})
        policies.append({"id": PEER_ROUTERS, "rules": [f"{PEER_ROUTERS}-relay"], "subjects": [PEER_ROUTERS]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


def _run_of(key_expr: str) -> str:
    """``truav/<run>/**`` for a key expression of that run."""
    return "/".join(key_expr.split("/")[:2]) + "/**"


# --- explain ---------------------------------------------------------------------------------------
def _matches(key_expr: str, pattern: str) -> bool:
    """Whether Zenoh key expression ``pattern`` includes ``key_expr`` (``*`` one chunk, ``**`` any)."""
    import zenoh
    return zenoh.KeyExpr(pattern).includes(zenoh.KeyExpr(key_expr))


def explain(table: Sequence[Grant], identity: str | None = None, key: str | None = None,
            peer_routers: Sequence[str] = ()) -> list[str]:
    """Lines telling who may put / subscribe where (optionally one identity, or who may use ``key``)."""
    ids = [g.identity for g in table]
    if identity is not None and not any(fnmatch.fnmatchcase(i, identity) for i in ids):
        raise CredentialsError(f"--identity {identity!r} matches no identity; known: {', '.join(ids[:8])} ...")
    out = []
    for g in table:
        if identity is not None and not fnmatch.fnmatchcase(g.identity, identity):
            continue
        if key is not None:
            verbs = [verb for verb, exprs in (("put", g.put), ("subscribe", g.subscribe), ("declare token", g.tokens),
                                              ("watch", g.watch)) if any(_matches(key, e) for e in exprs)]
            out.append(f"{g.identity:<11} {key}: " + (", ".join(f"may {v}" for v in verbs) if verbs else "DENIED"))
            continue
        out.append(f"{g.identity}  (certificate CN={g.identity!r})")
        for verb, exprs in (("put", g.put), ("subscribe", g.subscribe), ("token", g.tokens), ("watch", g.watch)):
            out.append(f"  {verb:<9} " + (", ".join(exprs) if exprs else "- (denied)"))
    if peer_routers and identity is None:
        out.append(f"{', '.join(sorted(peer_routers))} (the other routers): relay everything of the run both ways; "
                   f"each router enforces the grants of the clients connected to it")
    out.append("anyone else (no certificate, another CA, an expired certificate): cannot connect; "
               "anything not listed: denied by the router (default_permission deny)")
    return out


# --- certificates -----------------------------------------------------------------------------------
def _name(cn: str):
    from cryptography.x509.oid import NameOID
    from cryptography import x509
    return x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "TRUAV"),
                      x509.NameAttribute(NameOID.COMMON_NAME, cn)])


def _write_key(path: Path, key) -> None:
    from cryptography.hazmat.primitives import serialization
    data = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)  # private keys: owner only
    with os.fdopen(fd, "wb") as f:
        f.write(data)


def make_ca(cn: str = "TRUAV CA", days: int = DEFAULT_VALID_DAYS):
    """(key, certificate) of a new self-signed CA (EC P-256)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.asymmetric import ec
    key = ec.generate_private_key(ec.SECP256R1())
    now = dt.datetime.now(dt.timezone.utc)
    cert = (x509.CertificateBuilder().subject_name(_name(cn)).issuer_name(_name(cn))
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5)).not_valid_after(now + dt.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                         content_commitment=False, key_encipherment=False, data_encipherment=False,
                                         key_agreement=False, encipher_only=False, decipher_only=False), critical=True)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
            .sign(key, hashes.SHA256()))
    return key, cert


def make_leaf(ca_key, ca_cert, cn: str, hosts: Sequence[str] = DEFAULT_HOSTS, *, server: bool = False,
              not_before: dt.datetime | None = None, not_after: dt.datetime | None = None):
    """(key, certificate) for one component, signed by the CA; ``hosts`` become its SANs."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID
    key = ec.generate_private_key(ec.SECP256R1())
    now = dt.datetime.now(dt.timezone.utc)
    sans = []
    for h in hosts:
        try:
            sans.append(x509.IPAddress(ipaddress.ip_address(h)))
        except ValueError:
            sans.append(x509.DNSName(h))
    usage = [ExtendedKeyUsageOID.CLIENT_AUTH] + ([ExtendedKeyUsageOID.SERVER_AUTH] if server else [])
    cert = (x509.CertificateBuilder().subject_name(_name(cn)).issuer_name(ca_cert.subject)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(not_before or now - dt.timedelta(minutes=5))
            .not_valid_after(not_after or ca_cert.not_valid_after_utc)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.SubjectAlternativeName(sans), critical=False)
            .add_extension(x509.ExtendedKeyUsage(usage), critical=False)
            .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
            .sign(ca_key, hashes.SHA256()))
    return key, cert


def write_pair(directory: Path, stem: str, key, cert) -> tuple[Path, Path]:
    from cryptography.hazmat.primitives import serialization
    key_path, cert_path = directory / f"{stem}.key", directory / f"{stem}.pem"
    _write_key(key_path, key)
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    return key_path, cert_path


# --- zenoh configs ------------------------------------------------------------------------------------
TLS_FILE_KEYS = ("root_ca_certificate", "listen_private_key", "listen_certificate", "connect_private_key",
                 "connect_certificate")
"""The TLS settings that name files; a relative one is read next to its config file (transport.make_config)."""


def _file_namer(directory: Path | None):
    """Absolute paths into ``directory`` (one host's credentials, made where they are used), or bare
    file names (a bundle copied to another host: resolved against the config file's own directory)."""
    if directory is None:
        return lambda name: name
    d = directory.resolve()
    return lambda name: str(d / name)


# --- Zenoh's downsampling section: a rate cap per key ---------------------------------------------
RATE_CAP_MARGIN = 20.0
"""Each key's cap is this many times the rate the run needs on it. Zenoh's downsampler is a minimum
interval per key and session (a put less than 1/cap after the last one passed is dropped), not a
bucket, so the margin covers bursts: a late world or agent catching up sends two ticks' messages a
few ms apart (5 ms at 10 Hz stays allowed); a flood is cut to 200 puts/s per key from thousands."""
DOWNSAMPLING_ID = "truav-rate-caps"


def rate_caps(run: str, n_uavs: int, rate_hz: float, beacon_every: int = 1) -> tuple[tuple[str, float], ...]:
    """(key expression, puts/s) the router lets each session send on each key of a real-time run at
    ``rate_hz``: the rate the schema needs there (one per tick; beacons every ``beacon_every`` ticks;
    health every schema.HEALTH_PERIOD_S) times RATE_CAP_MARGIN. Control and fault keys (the
    supervisor's, rare and bursty: several faults at one instant) are not capped."""
    from truav.bus.schema import HEALTH_PERIOD_S
    per_tick = (keys.world_tick(run), keys.world_positions(run), keys.metrics_step(run), keys.metrics_episode(run))
    needed: list[tuple[str, float]] = [(k, rate_hz) for k in per_tick]
    for i in range(n_uavs):
        needed += [(keys.uav_obs(run, i), rate_hz),
                   (f"{keys.uav_beacon(run, i)}/**", rate_hz / beacon_every),  # range-limited ones too
                   (keys.uav_action(run, i), rate_hz), (keys.uav_state(run, i), rate_hz),
                   (keys.uav_health(run, i), 1.0 / HEALTH_PERIOD_S), (keys.controller_cmd(run, i), rate_hz)]
    return tuple((k, hz * RATE_CAP_MARGIN) for k, hz in needed)


def downsampling_config(caps: Sequence[tuple[str, float]]) -> list[dict]:
    """Zenoh's ``downsampling`` section: ``caps`` applied to what each session puts (ingress), so an
    identity flooding its own keys gets its cap, per key, and no more through the router."""
    return [{"id": DOWNSAMPLING_ID, "flows": ["ingress"], "messages": ["put"],
             "rules": [{"key_expr": k, "freq": float(hz)} for k, hz in caps]}]


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


def write_configs(directory: Path, files: dict[str, dict]) -> None:
    directory.mkdir(parents=True, exist_ok=True)
    for name, conf in files.items():
        _write_json(directory / name, conf)


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


def _write_json(path: Path, data: dict) -> None:
    path.write_text(json.dumps(data, indent=1) + "\n")  # JSON is JSON5


def issue(directory: str | os.PathLike[str], run: str, n_uavs: int, endpoint: str | None = None, *,
          hosts: Sequence[str] = DEFAULT_HOSTS, days: int = DEFAULT_VALID_DAYS, sites: Sequence[Site] = (),
          caps: Sequence[tuple[str, float]] = ()) -> Path:
    """Create the CA, one key + certificate per component and every zenoh config, in ``directory``.

    ``caps`` (:func:`rate_caps`, for one router's ``endpoint``) go into its config's ``downsampling``.

    ``endpoint`` is where the router listens and clients connect (made ``tls/``);
    ``hosts`` (names or IPs) go into the router certificate's SANs, so clients
    verify the router's name.  With ``sites`` instead (a router per host), each
    host gets a bundle ``directory/<site>/`` (itself a credentials directory for
    ``--creds``): the CA certificate, its router's key and certificate (CN
    ``router/<site>``, SANs its address), the keys of the components placed
    there and the configs of :func:`site_configs`.  The CA key stays in
    ``directory`` (mode 0600), in no bundle: keep it private, or delete it.
    """
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    os.chmod(d, 0o700)
    table = grants(run, n_uavs)
    ca_key, ca_cert = make_ca(days=days)
    write_pair(d, "ca", ca_key, ca_cert)
    os.replace(d / "ca.key", d / CA_KEY)
    if sites:
        configs = site_configs(run, n_uavs, sites)
        for site in sites:
            _issue_site(d / site.name, ca_key, ca_cert, site, configs[site.name],
                        site_manifest(run, n_uavs, sites, site))
        return d
    if endpoint is None:
        raise CredentialsError("issue: give the router's endpoint, or sites")
    ep = tls_endpoint(endpoint)
    host = ep.split("/", 1)[1].rsplit(":", 1)[0].strip("[]")
    all_hosts = tuple(dict.fromkeys([*hosts, host]))
    write_pair(d, ROUTER, *make_leaf(ca_key, ca_cert, ROUTER, all_hosts, server=True))
    for g in table:
        write_pair(d, file_stem(g.identity), *make_leaf(ca_key, ca_cert, g.identity, ()))
        _write_json(d / f"{file_stem(g.identity)}.json5", client_config(d, g.identity, [ep]))
    _write_json(d / ROUTER_CONFIG, router_config(d, [ep], table, caps=caps))
    _write_json(d / MANIFEST, {"run": run, "n_uavs": n_uavs, "endpoint": ep, "hosts": list(all_hosts),
                               "identities": [g.identity for g in table]})
    return d


def _issue_site(d: Path, ca_key, ca_cert, site: Site, files: dict[str, dict], manifest: dict) -> None:
    from cryptography.hazmat.primitives import serialization
    d.mkdir(parents=True, exist_ok=True)
    os.chmod(d, 0o700)
    (d / CA_CERT).write_bytes(ca_cert.public_bytes(serialization.Encoding.PEM))
    write_pair(d, ROUTER, *make_leaf(ca_key, ca_cert, site.router, tuple(manifest["hosts"]), server=True))
    for identity in site.identities:
        write_pair(d, file_stem(identity), *make_leaf(ca_key, ca_cert, identity, ()))
    write_configs(d, files)
    _write_json(d / MANIFEST, manifest)


@dataclass(frozen=True)
class Credentials:
    """A credentials directory made by :func:`issue`."""

    directory: Path
    run: str
    n_uavs: int
    endpoint: str
    identities: tuple[str, ...] = ()
    """The components with a key here (a host's bundle holds only its own)."""
    peer_routers: tuple[str, ...] = ()
    """The other routers of a multi-host deployment (empty for one host)."""

    def config_file(self, identity: str) -> Path:
        """The zenoh client config of ``identity`` (``router`` for the router's)."""
        path = self.directory / (ROUTER_CONFIG if identity == ROUTER else f"{file_stem(identity)}.json5")
        if not path.is_file():
            ids = ", ".join(self.identities[:8]) + (f" ... ({len(self.identities)} in all)"
                                                     if len(self.identities) > 8 else "")
            raise CredentialsError(f"--creds {self.directory}: no {path.name} (identities there: "
                                   f"router, {ids or 'no other'})")
        return path

    def table(self) -> tuple[Grant, ...]:
        return grants(self.run, self.n_uavs)


def load(directory: str | os.PathLike[str], run: str | None = None) -> Credentials:
    """The credentials in ``directory``; CredentialsError if absent or made for another run."""
    d = Path(directory)
    try:
        data = json.loads((d / MANIFEST).read_text())
        creds = Credentials(d, str(data["run"]), int(data["n_uavs"]), str(data["endpoint"]),
                            tuple(map(str, data.get("identities", ()))), tuple(map(str, data.get("peer_routers", ()))))
    except FileNotFoundError:
        raise CredentialsError(f"--creds {d}: no {MANIFEST}; create it with `truav-swarm certs --out {d}`") from None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise CredentialsError(f"--creds {d}: unreadable {MANIFEST} ({exc})") from None
    if run is not None and run != creds.run:
        raise CredentialsError(f"--creds {d} was made for run {creds.run!r}, not --run {run!r}")
    return creds


def secure_setup(out: Path, opts, n_uavs: int, endpoint: str):
    """For `truav-swarm up --secure`: fresh credentials in ``out/creds``; returns the router's
    arguments, the children's extra arguments and the supervisor's zenoh config."""
    import shutil

    from truav.bus.transport import make_config
    d = Path(out) / "creds"
    shutil.rmtree(d, ignore_errors=True)  # a new CA per run: an old run's certificates open nothing
    # Real time: each key capped at the rate it needs (with a margin); lock-step ticks as fast as the
    # processes answer, so no rate is known and nothing is capped.
    caps = () if opts.lockstep else rate_caps(opts.run, n_uavs, opts.rate_hz, opts.beacon_every)
    creds = load(issue(d, opts.run, n_uavs, endpoint, caps=caps), opts.run)
    sup = make_config(None, [creds.endpoint], config_file=creds.config_file(SUPERVISOR), connect_timeout_ms=5000)
    return ["--creds", str(d)], ["--creds", str(d)], sup

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
  or ``--creds DIR``) use the same material.

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
              subscribe=(keys.all_metrics(run), f"{p}/world/*", keys.all_beacons(run), keys.all_control(run),
                         keys.all_states(run), keys.all_commands(run)),  # traffic measured for the summary
              watch=(keys.all_alive(run),)),
        Grant(VIEW, subscribe=(keys.everything(run),)),
        Grant(REPLAY, put=(f"{r}/**",), subscribe=(keys.control(replay_run(run), "replay"),),
              tokens=(), watch=()),
    ]
    for i in range(n_uavs):
        table.append(Grant(
            keys.uav_identity(i),
            put=(keys.uav_beacon(run, i), keys.uav_action(run, i), keys.uav_state(run, i)),
            subscribe=(keys.uav_obs(run, i), keys.all_beacons(run), keys.world_tick(run), keys.all_control(run),
                       keys.controller_cmd(run, i)),
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


def acl_config(table: Sequence[Grant]) -> dict:
    """Zenoh ``access_control`` (default deny) that allows exactly what ``table`` says."""
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


def explain(table: Sequence[Grant], identity: str | None = None, key: str | None = None) -> list[str]:
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
def router_config(directory: Path, listen: Sequence[str], table: Sequence[Grant]) -> dict:
    d = directory.resolve()
    return {
        "mode": "router",
        "listen": {"endpoints": list(listen)},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"link": {"tls": {
            "root_ca_certificate": str(d / CA_CERT),
            "listen_private_key": str(d / f"{ROUTER}.key"),
            "listen_certificate": str(d / f"{ROUTER}.pem"),
            "enable_mtls": True,
            "close_link_on_expiration": True,
        }}},
        "access_control": acl_config(table),
    }


def client_config(directory: Path, identity: str, connect: Sequence[str]) -> dict:
    d, stem = directory.resolve(), file_stem(identity)
    return {
        "mode": "client",
        "connect": {"endpoints": list(connect)},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"link": {"tls": {
            "root_ca_certificate": str(d / CA_CERT),
            "connect_private_key": str(d / f"{stem}.key"),
            "connect_certificate": str(d / f"{stem}.pem"),
            "enable_mtls": True,
            "verify_name_on_connect": True,
        }}},
    }


def tls_endpoint(endpoint: str) -> str:
    """``tcp/HOST:PORT`` -> ``tls/HOST:PORT`` (a tls endpoint is kept)."""
    proto, sep, rest = endpoint.partition("/")
    if not sep or proto not in ("tcp", "tls"):
        raise CredentialsError(f"endpoint {endpoint!r}: --secure needs tcp/HOST:PORT or tls/HOST:PORT")
    return f"tls/{rest}"


def _write_json(path: Path, data: dict) -> None:
    path.write_text(json.dumps(data, indent=1) + "\n")  # JSON is JSON5


def issue(directory: str | os.PathLike[str], run: str, n_uavs: int, endpoint: str, *,
          hosts: Sequence[str] = DEFAULT_HOSTS, days: int = DEFAULT_VALID_DAYS) -> Path:
    """Create the CA, one key + certificate per component and every zenoh config, in ``directory``.

    ``endpoint`` is where the router listens and clients connect (made ``tls/``);
    ``hosts`` (names or IPs) go into the router certificate's SANs, so clients
    verify the router's name.  The CA key stays in the directory (mode 0600):
    keep the directory private, or delete ca.key once issued.
    """
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    os.chmod(d, 0o700)
    ep = tls_endpoint(endpoint)
    table = grants(run, n_uavs)
    ca_key, ca_cert = make_ca(days=days)
    write_pair(d, "ca", ca_key, ca_cert)
    os.replace(d / "ca.key", d / CA_KEY)
    host = ep.split("/", 1)[1].rsplit(":", 1)[0].strip("[]")
    all_hosts = tuple(dict.fromkeys([*hosts, host]))
    write_pair(d, ROUTER, *make_leaf(ca_key, ca_cert, ROUTER, all_hosts, server=True))
    for g in table:
        write_pair(d, file_stem(g.identity), *make_leaf(ca_key, ca_cert, g.identity, ()))
        _write_json(d / f"{file_stem(g.identity)}.json5", client_config(d, g.identity, [ep]))
    _write_json(d / ROUTER_CONFIG, router_config(d, [ep], table))
    _write_json(d / MANIFEST, {"run": run, "n_uavs": n_uavs, "endpoint": ep, "hosts": list(all_hosts),
                               "identities": [g.identity for g in table]})
    return d


@dataclass(frozen=True)
class Credentials:
    """A credentials directory made by :func:`issue`."""

    directory: Path
    run: str
    n_uavs: int
    endpoint: str

    def config_file(self, identity: str) -> Path:
        """The zenoh client config of ``identity`` (``router`` for the router's)."""
        path = self.directory / (ROUTER_CONFIG if identity == ROUTER else f"{file_stem(identity)}.json5")
        if not path.is_file():
            raise CredentialsError(f"--creds {self.directory}: no {path.name} (identities there: "
                                   f"router, world, recorder, supervisor, view, replay, controller, uav/0..uav/{self.n_uavs - 1})")
        return path

    def table(self) -> tuple[Grant, ...]:
        return grants(self.run, self.n_uavs)


def load(directory: str | os.PathLike[str], run: str | None = None) -> Credentials:
    """The credentials in ``directory``; CredentialsError if absent or made for another run."""
    d = Path(directory)
    try:
        data = json.loads((d / MANIFEST).read_text())
        creds = Credentials(d, str(data["run"]), int(data["n_uavs"]), str(data["endpoint"]))
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
    creds = load(issue(d, opts.run, n_uavs, endpoint), opts.run)
    sup = make_config(None, [creds.endpoint], config_file=creds.config_file(SUPERVISOR), connect_timeout_ms=5000)
    return ["--creds", str(d)], ["--creds", str(d)], sup

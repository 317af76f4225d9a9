"""Certificates and credentials directories of a secure swarm: one CA, one key and certificate per
component (made with the ``cryptography`` library, imported when used), written with every zenoh config
by :func:`issue` and read back by :func:`load` (``--creds DIR``)."""

from __future__ import annotations

import datetime as dt
import ipaddress
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from truav.bus.acl import ROUTER, CredentialsError, Grant, file_stem, grants
from truav.bus.secure_configs import (CA_CERT, CA_KEY, DEFAULT_HOSTS, INLINE_SUFFIX, MANIFEST, ROUTER_CONFIG,
                                      TLS_FILE_KEYS, Site,
                                      _write_json, client_config, inline_material, router_config, site_configs,
                                      site_manifest, tls_endpoint, write_configs)

DEFAULT_VALID_DAYS = 30


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
    builder = (x509.CertificateBuilder().subject_name(_name(cn)).issuer_name(ca_cert.subject)
               .public_key(key.public_key()).serial_number(x509.random_serial_number())
               .not_valid_before(not_before or now - dt.timedelta(minutes=5))
               .not_valid_after(not_after or ca_cert.not_valid_after_utc)
               .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True))
    if sans:  # a client certificate names no host; cryptography >= 51 refuses an empty SAN extension
        builder = builder.add_extension(x509.SubjectAlternativeName(sans), critical=False)
    cert = (builder.add_extension(x509.ExtendedKeyUsage(usage), critical=False)
            .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
            .sign(ca_key, hashes.SHA256()))
    return key, cert


def write_pair(directory: Path, stem: str, key, cert) -> tuple[Path, Path]:
    from cryptography.hazmat.primitives import serialization
    key_path, cert_path = directory / f"{stem}.key", directory / f"{stem}.pem"
    _write_key(key_path, key)
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    return key_path, cert_path



def issue(directory: str | os.PathLike[str], run: str, n_uavs: int, endpoint: str | None = None, *,
          hosts: Sequence[str] = DEFAULT_HOSTS, days: int = DEFAULT_VALID_DAYS, sites: Sequence[Site] = (),
          caps: Sequence[tuple[str, float]] = (), batch_group_size: int = 1) -> Path:
    """Create the CA, one key + certificate per component and every zenoh config, in ``directory``.

    ``caps`` (:func:`rate_caps`, for one router's ``endpoint``) go into its config's ``downsampling``.
    ``batch_group_size``: see :func:`truav.bus.acl.grants` (``--batch-beacons``).

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
    table = grants(run, n_uavs, batch_group_size)
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
    # Every config holds its certificates and key inline (inline_material): plain Zenoh loads it from any
    # working directory; the .key/.pem files stay beside it for other tools.
    for g in table:
        write_pair(d, file_stem(g.identity), *make_leaf(ca_key, ca_cert, g.identity, ()))
        _write_json(d / f"{file_stem(g.identity)}.json5", inline_material(client_config(d, g.identity, [ep]), d),
                    secret=True)
    _write_json(d / ROUTER_CONFIG, inline_material(router_config(d, [ep], table, caps=caps), d), secret=True)
    _write_json(d / MANIFEST, {"run": run, "n_uavs": n_uavs, "endpoint": ep, "hosts": list(all_hosts),
                               "identities": [g.identity for g in table], "batch_group_size": batch_group_size})
    return d


def _issue_site(d: Path, ca_key, ca_cert, site: Site, files: dict[str, dict], manifest: dict) -> None:
    from cryptography.hazmat.primitives import serialization
    d.mkdir(parents=True, exist_ok=True)
    os.chmod(d, 0o700)
    (d / CA_CERT).write_bytes(ca_cert.public_bytes(serialization.Encoding.PEM))
    write_pair(d, ROUTER, *make_leaf(ca_key, ca_cert, site.router, tuple(manifest["hosts"]), server=True))
    for identity in site.identities:
        write_pair(d, file_stem(identity), *make_leaf(ca_key, ca_cert, identity, ()))
    write_configs(d, files, inline=True)
    _write_json(d / MANIFEST, manifest)


def _pem(obj) -> bytes:
    from cryptography.hazmat.primitives import serialization
    if hasattr(obj, "private_bytes"):
        return obj.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                 serialization.NoEncryption())
    return obj.public_bytes(serialization.Encoding.PEM)


def site_bundles(run: str, n_uavs: int, sites: Sequence[Site], *,
                 days: int = DEFAULT_VALID_DAYS) -> dict[str, dict[str, bytes]]:
    """The bundles of :func:`issue` with ``sites``, made in memory and written nowhere: per site, its files
    by name (the CA certificate, its router's and its components' keys and certificates, their configs
    with that material inline, the manifest). The CA key is in none and is dropped on return, so the
    run's certificates are the only ones it ever signs (`truav-swarm up --ray --secure`)."""
    import base64
    ca_key, ca_cert = make_ca(days=days)
    configs = site_configs(run, n_uavs, sites)
    out: dict[str, dict[str, bytes]] = {}
    for site in sites:
        manifest = site_manifest(run, n_uavs, sites, site)
        files = {CA_CERT: _pem(ca_cert)}
        for stem, cn, hosts in [(ROUTER, site.router, tuple(manifest["hosts"])),
                                *((file_stem(i), i, ()) for i in site.identities)]:
            key, cert = make_leaf(ca_key, ca_cert, cn, hosts, server=stem == ROUTER)
            files[f"{stem}.key"], files[f"{stem}.pem"] = _pem(key), _pem(cert)
        for name, conf in configs[site.name].items():
            tls = conf["transport"]["link"]["tls"]
            for setting in TLS_FILE_KEYS:  # bare file names of this bundle, put inline (inline_material)
                if setting in tls:
                    tls[setting + INLINE_SUFFIX] = base64.b64encode(files[tls.pop(setting)]).decode("ascii")
            files[name] = (json.dumps(conf, indent=1) + "\n").encode()
        files[MANIFEST] = (json.dumps(manifest, indent=1) + "\n").encode()
        out[site.name] = files
    return out


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
    batch_group_size: int = 1
    """Agents per process whose beacons go out batched (``--batch-beacons``); 1: none."""

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
        return grants(self.run, self.n_uavs, self.batch_group_size)


def load(directory: str | os.PathLike[str], run: str | None = None) -> Credentials:
    """The credentials in ``directory``; CredentialsError if absent or made for another run."""
    d = Path(directory)
    try:
        data = json.loads((d / MANIFEST).read_text())
        creds = Credentials(d, str(data["run"]), int(data["n_uavs"]), str(data["endpoint"]),
                            tuple(map(str, data.get("identities", ()))), tuple(map(str, data.get("peer_routers", ()))),
                            int(data.get("batch_group_size", 1)))
    except FileNotFoundError:
        raise CredentialsError(f"--creds {d}: no {MANIFEST}; create it with `truav-swarm certs --out {d}`") from None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise CredentialsError(f"--creds {d}: unreadable {MANIFEST} ({exc})") from None
    if run is not None and run != creds.run:
        raise CredentialsError(f"--creds {d} was made for run {creds.run!r}, not --run {run!r}")
    return creds


"""Security material for a locked bus (its parts: :mod:`truav.bus.acl`, :mod:`truav.bus.secure_configs`,
:mod:`truav.bus.certs`, :mod:`truav.bus.rate_caps`; every name is re-exported here): one CA, one certificate per component, the router's ACL.

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

How Zenoh applies the table (zenoh 1.10, checked by ``tests/swarm/test_security.py``):
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

import shutil
from pathlib import Path

from truav.bus.acl import (  # noqa: F401  (re-exported: callers use security.<name>)
    ALL_MESSAGES, CONTROLLER, PEER_ROUTERS, RECORDER, REPLAY, REPLAY_RUN_SUFFIX, ROUTER, SUPERVISOR, VIEW, WORLD,
    CredentialsError, Grant, _matches, acl_config, component_names, explain, file_stem, grants,
    replay_run)
from truav.bus.certs import (  # noqa: F401
    DEFAULT_VALID_DAYS, Credentials, issue, load, make_ca, make_leaf, write_pair)
from truav.bus.rate_caps import DOWNSAMPLING_ID, RATE_CAP_MARGIN, downsampling_config, rate_caps  # noqa: F401
from truav.bus.secure_configs import (  # noqa: F401
    CA_CERT, CA_KEY, DEFAULT_HOSTS, MANIFEST, ROUTER_CONFIG, TLS_FILE_KEYS, TLS_PROBE, Site, answers_tls,
    client_config, router_config, site_configs, site_manifest, tls_endpoint,
    write_configs)
from truav.bus.zenoh_config import make_config


def secure_setup(out: Path, opts, n_uavs: int, endpoint: str, share_every_ticks: int = 0):
    """For `truav-swarm up --secure`: fresh credentials in ``out/creds``; returns the router's
    arguments, the children's extra arguments and the supervisor's zenoh config. ``share_every_ticks``:
    federated TRUAV's share period in ticks (0: no sharing), for its rate caps."""
    d = Path(out) / "creds"
    shutil.rmtree(d, ignore_errors=True)  # a new CA per run: an old run's certificates open nothing
    # Real time: each key capped at the rate it needs (with a margin); lock-step ticks as fast as the
    # processes answer, so no rate is known and nothing is capped.
    caps = () if opts.lockstep else rate_caps(opts.run, n_uavs, opts.rate_hz, opts.beacon_every,
                                                 share_every_ticks)
    batch = opts.agents_per_process if getattr(opts, "batch_beacons", False) else 1
    creds = load(issue(d, opts.run, n_uavs, endpoint, caps=caps, batch_group_size=batch), opts.run)
    sup = make_config(None, [creds.endpoint], config_file=creds.config_file(SUPERVISOR), connect_timeout_ms=5000)
    return ["--creds", str(d)], ["--creds", str(d)], sup

"""The credentials of a secure swarm (truav.bus.certs) with the cryptography release installed: every
certificate is signed by the run's CA, the router's names its hosts, a client's names none (cryptography
51 refuses an empty SubjectAlternativeName: a client certificate carries no such extension at all).
CI runs this file a second time with the oldest cryptography the pyproject allows."""

from __future__ import annotations

import os
from pathlib import Path

import cryptography
import pytest
from cryptography import x509

from truav.bus import certs


def test_the_expected_cryptography_is_the_one_tested() -> None:
    """CI's run with the oldest release sets TRUAV_EXPECT_CRYPTOGRAPHY: that one, not the venv's, is imported."""
    expected = os.environ.get("TRUAV_EXPECT_CRYPTOGRAPHY")
    if expected is None:
        pytest.skip("not CI's oldest-release run")
    assert cryptography.__version__.startswith(expected), cryptography.__version__


def _san(cert: x509.Certificate) -> list[str] | None:
    try:
        ext = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        return None
    return [str(v) for v in ext.get_values_for_type(x509.DNSName)] + \
        [str(v) for v in ext.get_values_for_type(x509.IPAddress)]


def test_issued_certificates_chain_to_the_ca_and_name_the_right_hosts(tmp_path: Path) -> None:
    d = certs.issue(tmp_path / "creds", "demo", 2, "tls/127.0.0.1:7447")
    ca = x509.load_pem_x509_certificate((d / "ca.pem").read_bytes())
    leaves = {p.stem: x509.load_pem_x509_certificate(p.read_bytes()) for p in d.glob("*.pem") if p.stem != "ca"}
    assert {"router", "world"} <= leaves.keys() and len(leaves) >= 4, sorted(leaves)
    for stem, cert in leaves.items():
        cert.verify_directly_issued_by(ca)  # raises if not signed by the run's CA
        assert cert.not_valid_after_utc <= ca.not_valid_after_utc, stem
    assert "127.0.0.1" in (_san(leaves["router"]) or [])
    assert _san(leaves["world"]) is None  # a client names no host


def test_certs_command_works_with_this_release(tmp_path: Path, capsys) -> None:
    """`truav-swarm certs` end to end, with whatever cryptography the environment resolved."""
    from truav.cli.swarm import main
    out = tmp_path / "creds"
    assert main(["certs", "--run", "demo", "--agents", "2", "--out", str(out)]) == 0, capsys.readouterr().err
    assert (out / "ca.pem").is_file() and (out / "router.pem").is_file()

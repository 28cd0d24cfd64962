"""The server's certificate (made once, kept, replaced when it no longer fits) and the client trust list."""

from __future__ import annotations

import typing
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest
from asyncua import ua
from asyncua.common.utils import ServiceError
from asyncua.crypto import cert_gen
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from gateway.sinks.opcua.endpoints import SecurityName
from gateway.sinks.opcua.security import (
    POLICY_TYPES,
    ClientCertificates,
    Pki,
    application_uris,
    ensure_certificate,
)

URI = "urn:host:cnc-gateway"
CLIENT = "urn:tests:client"


def test_every_configurable_endpoint_has_an_asyncua_policy() -> None:
    assert set(typing.get_args(SecurityName)) == set(POLICY_TYPES)


def test_the_certificate_is_made_once_and_kept_and_replaced_for_another_uri(tmp_path: Path) -> None:
    pki = Pki(tmp_path / "pki")
    cert = ensure_certificate(pki, URI, "cnc-gateway", ["gw.plant.local", "10.1.2.3"])
    assert URI in application_uris(cert)
    names = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert "gw.plant.local" in names.get_values_for_type(x509.DNSName)
    assert pki.key.stat().st_mode & 0o077 == 0  # the private key is the owner's alone
    first = pki.cert.read_bytes()
    ensure_certificate(pki, URI, "cnc-gateway", [])
    assert pki.cert.read_bytes() == first
    ensure_certificate(pki, "urn:renamed-host:cnc-gateway", "cnc-gateway", [])
    assert pki.cert.read_bytes() != first
    assert len(list(pki.own.glob("cert.der.*.old"))) == 1  # the old one is kept aside, not lost


def client_cert(name: str, *, days: int = 30, expired: bool = False) -> x509.Certificate:
    key = cert_gen.generate_private_key()
    if not expired:
        return cert_gen.generate_self_signed_app_certificate(
            key,
            name,
            {},
            [x509.UniformResourceIdentifier(CLIENT)],
            [ExtendedKeyUsageOID.CLIENT_AUTH],
            days=days,
        )
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)])
    now = datetime.now(UTC)
    return (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - timedelta(days=60))
        .not_valid_after(now - timedelta(days=1))
        .add_extension(x509.SubjectAlternativeName([x509.UniformResourceIdentifier(CLIENT)]), critical=False)
        .sign(key, hashes.SHA256())
    )


def app() -> ua.ApplicationDescription:
    return ua.ApplicationDescription(ApplicationUri=CLIENT, ApplicationType=ua.ApplicationType.Client)


async def refused(check: ClientCertificates, cert: x509.Certificate) -> str:
    with pytest.raises(ServiceError) as info:
        await check(cert, app())
    return ua.StatusCode(info.value.code).name


async def test_untrusted_and_expired_certificates_are_refused_and_kept_in_rejected(tmp_path: Path) -> None:
    pki = Pki(tmp_path / "pki")
    pki.create()
    check = ClientCertificates(pki)
    stranger, expired = client_cert("stranger"), client_cert("old", expired=True)
    assert await refused(check, stranger) == "BadCertificateUntrusted"
    der = expired.public_bytes(serialization.Encoding.DER)
    (pki.trusted / "old.der").write_bytes(der)  # trusted, but out of date
    assert await refused(check, expired) == "BadCertificateTimeInvalid"
    names = sorted(p.name for p in pki.rejected.iterdir())
    assert len(names) == 2 and names[0].startswith("old [") and names[1].startswith("stranger [")
    # An administrator trusts the stranger by moving its file; the next attempt is accepted.
    moved = next(pki.rejected.glob("stranger*"))
    moved.rename(pki.trusted / moved.name)
    await check(stranger, app())


async def test_a_certificate_for_another_application_is_refused(tmp_path: Path) -> None:
    pki = Pki(tmp_path / "pki")
    pki.create()
    cert = client_cert("scada")
    (pki.trusted / "scada.der").write_bytes(cert.public_bytes(serialization.Encoding.DER))
    check = ClientCertificates(pki)
    await check(cert, app())
    other = ua.ApplicationDescription(
        ApplicationUri="urn:someone-else", ApplicationType=ua.ApplicationType.Client
    )
    with pytest.raises(ServiceError) as info:
        await check(cert, other)
    assert ua.StatusCode(info.value.code).name == "BadCertificateUriInvalid"


async def test_certificates_issued_by_a_trusted_ca_are_accepted(tmp_path: Path) -> None:
    ca_key = cert_gen.generate_private_key()
    ca = cert_gen.generate_self_signed_app_certificate(
        ca_key, "Plant CA", {}, [], [], days=30
    )  # [] usage: a CA
    key = cert_gen.generate_private_key()
    csr = cert_gen.generate_app_certificate_signing_request(
        key, "hmi-3", {}, [x509.UniformResourceIdentifier(CLIENT)], [ExtendedKeyUsageOID.CLIENT_AUTH]
    )
    cert = cert_gen.sign_certificate_request(csr, ca, ca_key, days=30)
    pki = Pki(tmp_path / "pki")
    pki.create()
    (pki.trusted / "plant-ca.pem").write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    await ClientCertificates(pki)(cert, app())

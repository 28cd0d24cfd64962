"""Secure endpoints over real TCP: the server certificate is made once and kept; a client with a trusted
certificate connects with Basic256Sha256 SignAndEncrypt and logs in; an untrusted one is refused and its
certificate lands in rejected/, from where an administrator moves it to trusted/; the secure profile
offers no None endpoint."""

from __future__ import annotations

from pathlib import Path

import pytest
from asyncua import ua
from asyncua.crypto import cert_gen
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256, SecurityPolicyNone
from cryptography import x509
from cryptography.hazmat.primitives import serialization
from cryptography.x509.oid import ExtendedKeyUsageOID

from tests.integration.security.conftest import MACHINE, USERS, Rig, secure_gateway
from tests.opcua_client import Client

CLIENT_URI = "urn:cnc-gateway-tests:scada"


def client_certificate(folder: Path, name: str) -> tuple[Path, Path]:
    key = cert_gen.generate_private_key()
    cert = cert_gen.generate_self_signed_app_certificate(
        key,
        name,
        {},
        [x509.UniformResourceIdentifier(CLIENT_URI), x509.DNSName("localhost")],
        [ExtendedKeyUsageOID.CLIENT_AUTH],
        days=30,
    )
    folder.mkdir(parents=True, exist_ok=True)
    cert_path, key_path = folder / f"{name}.der", folder / f"{name}.pem"
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.DER))
    key_path.write_bytes(cert_gen.dump_private_key_as_pem(key))
    return cert_path, key_path


async def secure_client(rig: Rig, cert: Path, key: Path, user: str = "otto") -> Client:
    client = Client(rig.endpoint, timeout=5)
    client.application_uri = CLIENT_URI
    client.set_user(user)
    client.set_password(USERS[user][1])
    await client.set_security(
        SecurityPolicyBasic256Sha256,
        str(cert),
        str(key),
        server_certificate=str(rig.state_dir / "pki" / "own" / "cert.der"),
        mode=ua.MessageSecurityMode.SignAndEncrypt,
    )
    return client


async def test_signed_and_encrypted_sessions_for_trusted_clients_only(tmp_path: Path) -> None:
    trusted_cert, trusted_key = client_certificate(tmp_path / "clients", "scada")
    stranger_cert, stranger_key = client_certificate(tmp_path / "clients", "stranger")
    async with secure_gateway(tmp_path, simulator=False, opcua={"profile": "secure"}) as rig:
        pki = rig.state_dir / "pki"
        first = (pki / "own" / "cert.der").read_bytes()
        server_cert = x509.load_der_x509_certificate(first)
        uris = server_cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        assert rig.gateway.sink("opcua").application_uri in uris.get_values_for_type(
            x509.UniformResourceIdentifier
        )

        probe = Client(rig.endpoint, timeout=5)
        endpoints = await probe.connect_and_get_server_endpoints()
        modes = {(e.SecurityPolicyUri.rsplit("#", 1)[1], e.SecurityMode) for e in endpoints}
        assert ("None", ua.MessageSecurityMode.None_) not in modes
        assert ("Basic256Sha256", ua.MessageSecurityMode.SignAndEncrypt) in modes
        assert ("Basic256Sha256", ua.MessageSecurityMode.Sign) in modes
        assert ("Aes256_Sha256_RsaPss", ua.MessageSecurityMode.SignAndEncrypt) in modes
        assert ("Aes128_Sha256_RsaOaep", ua.MessageSecurityMode.SignAndEncrypt) in modes

        (pki / "trusted" / "scada.der").write_bytes(trusted_cert.read_bytes())
        client = await secure_client(rig, trusted_cert, trusted_key)
        async with client:
            level = await client.get_node(f"ns=2;s={MACHINE}/Feed/Override").read_attribute(
                ua.AttributeIds.UserAccessLevel
            )
            assert level.Value.Value & ua.AccessLevel.CurrentWrite.mask  # logged in as the operator

        stranger = await secure_client(rig, stranger_cert, stranger_key)
        with pytest.raises(ua.uaerrors.BadCertificateUntrusted):
            async with stranger:
                pass
        [rejected] = list((pki / "rejected").glob("*.der"))
        assert "stranger" in rejected.name and rejected.read_bytes() == stranger_cert.read_bytes()

        rejected.rename(pki / "trusted" / rejected.name)  # what an administrator does; no restart needed
        stranger = await secure_client(rig, stranger_cert, stranger_key)
        async with stranger:
            assert await stranger.get_node(f"ns=2;s={MACHINE}/Feed/Override").read_browse_name()

    async with secure_gateway(tmp_path, simulator=False, opcua={"profile": "secure"}) as rig:
        assert (rig.state_dir / "pki" / "own" / "cert.der").read_bytes() == first  # reused, not regenerated


async def test_on_the_none_endpoint_a_client_certificate_is_ignored_not_refused(tmp_path: Path) -> None:
    """UaExpert and others send their certificate on None channels too; OPC UA says to ignore it there."""
    cert, _ = client_certificate(tmp_path / "clients", "uaexpert")
    async with secure_gateway(tmp_path, simulator=False, opcua={"profile": "standard"}) as rig:
        client = rig.client("otto")
        client.application_uri = CLIENT_URI
        policy = SecurityPolicyNone(host_cert=x509.load_der_x509_certificate(cert.read_bytes()))
        client.security_policy = client.uaclient.security_policy = policy
        async with client:
            assert await client.get_node(f"ns=2;s={MACHINE}/Feed/Override").read_browse_name()
        assert not list((rig.state_dir / "pki" / "rejected").iterdir())

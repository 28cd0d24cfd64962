"""A signed and encrypted session, configured with the driver's security string."""

from __future__ import annotations

import asyncio
from pathlib import Path

from asyncua import Server, ua
from asyncua.crypto.cert_gen import setup_self_signed_certificate
from cryptography.x509.oid import ExtendedKeyUsageOID

from gateway.sources.opcua.client import certificate_uri
from tests.integration.opcua.conftest import make_machine, source_for
from tests.waiting import free_port, wait_until


async def test_basic256sha256_sign_and_encrypt_session(tmp_path: Path) -> None:
    server_key, server_cert = tmp_path / "server-key.pem", tmp_path / "server-cert.der"
    client_key, client_cert = tmp_path / "client-key.pem", tmp_path / "client-cert.der"
    await setup_self_signed_certificate(
        server_key, server_cert, "urn:test:controller", "localhost", [ExtendedKeyUsageOID.SERVER_AUTH], {}
    )
    await setup_self_signed_certificate(
        client_key, client_cert, "urn:test:gateway", "localhost", [ExtendedKeyUsageOID.CLIENT_AUTH], {}
    )
    security = f"Basic256Sha256,SignAndEncrypt,{client_cert},{client_key}"
    assert await certificate_uri(security) == "urn:test:gateway"

    endpoint = f"opc.tcp://127.0.0.1:{free_port()}/secure"
    server = Server()
    await server.init()
    server.set_endpoint(endpoint)
    await server.set_application_uri("urn:test:controller")
    server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt])  # no unsecured endpoint
    await server.load_certificate(str(server_cert))
    await server.load_private_key(str(server_key))
    ns = await server.register_namespace("urn:test")
    await server.nodes.objects.add_variable(ua.NodeId("Speed", ns), "Speed", 4.5)
    await server.start()
    try:
        machine = make_machine(
            endpoint, [{"path": "Speed", "source": f"ns={ns};s=Speed", "type": "Double"}], security=security
        )
        async with source_for(machine) as source:
            task = asyncio.create_task(source.run())
            try:
                await wait_until(
                    lambda: machine.nodes["Speed"].sample.good, message="value over the secure channel"
                )
                assert machine.nodes["Speed"].sample.value == 4.5
            finally:
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)
    finally:
        await server.stop()

"""TLS to the broker, with a CA, server and client certificates made on the fly."""

from __future__ import annotations

import datetime as dt
import ipaddress
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID

from gateway.config.mapping import MachineMapping
from tests.integration.mqtt.conftest import Mosquitto, Recorder, mqtt_config, subscriber
from tests.integration.mqtt.test_sink import MAPPING, ingest, running
from tests.trees import MappedTree
from tests.waiting import free_port, wait_until


def _key() -> ec.EllipticCurvePrivateKey:
    return ec.generate_private_key(ec.SECP256R1())


def _write(path: Path, key: ec.EllipticCurvePrivateKey, cert: x509.Certificate) -> tuple[Path, Path]:
    path.with_suffix(".key").write_bytes(
        key.private_bytes(
            serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
        )
    )
    path.with_suffix(".crt").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    return path.with_suffix(".crt"), path.with_suffix(".key")


def make_ca(directory: Path, name: str) -> tuple[ec.EllipticCurvePrivateKey, x509.Certificate, Path]:
    key = _key()
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)])
    now = dt.datetime.now(dt.UTC)
    cert = (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(minutes=5))
        .not_valid_after(now + dt.timedelta(days=1))
        .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
        .add_extension(
            x509.KeyUsage(False, False, False, False, False, True, True, False, False), critical=True
        )
        .sign(key, hashes.SHA256())
    )
    crt, _ = _write(directory / name, key, cert)
    return key, cert, crt


def issue(
    directory: Path, name: str, ca_key: ec.EllipticCurvePrivateKey, ca: x509.Certificate, *, server: bool
) -> tuple[Path, Path]:
    key = _key()
    now = dt.datetime.now(dt.UTC)
    builder = (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)]))
        .issuer_name(ca.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(minutes=5))
        .not_valid_after(now + dt.timedelta(days=1))
    )
    if server:
        builder = builder.add_extension(
            x509.SubjectAlternativeName(
                [x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]
            ),
            critical=False,
        )
    return _write(directory / name, key, builder.sign(ca_key, hashes.SHA256()))


async def test_tls_with_a_client_certificate_and_a_verified_server(
    tmp_path: Path, recorders: list[Recorder]
) -> None:
    pki = tmp_path / "pki"
    pki.mkdir()
    ca_key, ca, ca_file = make_ca(pki, "test-ca")
    server_crt, server_key = issue(pki, "broker", ca_key, ca, server=True)
    client_crt, client_key = issue(pki, "gateway", ca_key, ca, server=False)
    _, _, stranger_ca = make_ca(pki, "other-ca")
    broker = Mosquitto(
        tmp_path / "tls-broker",
        free_port(),
        extra=(f"cafile {ca_file}\ncertfile {server_crt}\nkeyfile {server_key}\nrequire_certificate true\n"),
    )
    broker.start()
    try:
        rec = subscriber(recorders, broker.port, tls=(ca_file, client_crt, client_key))
        tree = MappedTree([MachineMapping.model_validate(MAPPING)])
        tls = {"ca": str(ca_file), "cert": str(client_crt), "key": str(client_key)}
        async with running(tree, mqtt_config(broker.port, tls=tls), tmp_path / "state") as sink:
            await wait_until(lambda: sink.online, message="a TLS connection")
            assert sink.endpoint.startswith("mqtts://")
            ingest(tree.machines["m1"], "Axes/X/Position", 7.5)
            await wait_until(lambda: (rec.last_json("cnc/m1/axes/x/position") or {}).get("value") == 7.5)

        # A broker whose certificate our CA did not sign is refused, with a reason a person can act on.
        wrong = {"ca": str(stranger_ca), "cert": str(client_crt), "key": str(client_key)}
        other = MappedTree([MachineMapping.model_validate(MAPPING)])
        async with running(other, mqtt_config(broker.port, tls=wrong), tmp_path / "state2") as sink:
            await wait_until(lambda: "not trusted" in sink.last_error, message="the certificate refusal")
            assert not sink.online
            assert "not trusted" in other.machines["m1"].nodes["Status/MqttState"].sample.value
    finally:
        broker.stop()


def test_missing_tls_files_stop_the_start_with_a_clear_error(tmp_path: Path) -> None:
    import pytest

    from gateway.errors import SinkError
    from gateway.sinks.mqtt.sink import MqttSink

    tree = MappedTree([MachineMapping.model_validate(MAPPING)])
    with pytest.raises(SinkError, match=r"mqtt\.tls: cannot load .*nope\.pem"):
        MqttSink(tree, mqtt_config(1, tls={"ca": "nope.pem"}), tmp_path, tree.mappings)

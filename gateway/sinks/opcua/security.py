"""Secure OPC UA endpoints: the server's own certificate, and which client certificates it trusts.

Folders under `<state_dir>/pki/`, laid out as in other OPC UA servers:

    own/cert.der, own/key.pem   the server's application certificate, generated on first start
                                (self-signed, with the application URI) and reused afterwards
    trusted/                    client certificates (DER or PEM) the server accepts, and CA
                                certificates whose signatures it accepts
    rejected/                   certificates the server refused, for an administrator to move to trusted/

A client certificate is accepted when it is within its validity period, names
the client's application URI, and is in trusted/ (or was issued by a CA
certificate there). Anything else is refused (BadCertificateUntrusted,
BadCertificateTimeInvalid, ...), logged, and copied to rejected/. The trust list
is read again whenever trusted/ changes, so moving a file there takes effect
on the client's next attempt, without a restart.

Operates on the asyncua Server passed in; only gateway/sinks/opcua/server.py
imports the server API itself.
"""

from __future__ import annotations

import asyncio
import hashlib
import ipaddress
import logging
import os
import re
import socket
from collections.abc import Iterable
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

from asyncua import ua
from asyncua.common.utils import ServiceError
from asyncua.crypto import cert_gen
from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions
from cryptography import x509
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from gateway.errors import NotFound, SinkError
from gateway.shims.ua import new_status_code
from gateway.sinks.opcua.endpoints import is_secure

log = logging.getLogger(__name__)

POLICY_TYPES: dict[str, ua.SecurityPolicyType] = {
    "None": ua.SecurityPolicyType.NoSecurity,
    "Basic256Sha256_Sign": ua.SecurityPolicyType.Basic256Sha256_Sign,
    "Basic256Sha256_SignAndEncrypt": ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt,
    "Aes128_Sha256_RsaOaep_Sign": ua.SecurityPolicyType.Aes128Sha256RsaOaep_Sign,
    "Aes128_Sha256_RsaOaep_SignAndEncrypt": ua.SecurityPolicyType.Aes128Sha256RsaOaep_SignAndEncrypt,
    "Aes256_Sha256_RsaPss_Sign": ua.SecurityPolicyType.Aes256Sha256RsaPss_Sign,
    "Aes256_Sha256_RsaPss_SignAndEncrypt": ua.SecurityPolicyType.Aes256Sha256RsaPss_SignAndEncrypt,
}

CERT_DAYS = 5 * 365
RENEW_BEFORE = timedelta(days=1)
MAX_REJECTED = 500  # certificates kept in rejected/; beyond that, refusals are only logged


class Pki:
    """The folders of the server's certificate store."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.own = root / "own"
        self.trusted = root / "trusted"
        self.rejected = root / "rejected"

    @property
    def cert(self) -> Path:
        return self.own / "cert.der"

    @property
    def key(self) -> Path:
        return self.own / "key.pem"

    def create(self) -> None:
        for folder in (self.own, self.trusted, self.rejected):
            folder.mkdir(parents=True, exist_ok=True)
        os.chmod(self.own, 0o700)


def thumbprint(cert: x509.Certificate) -> str:
    """SHA-1 of the DER form, upper-case hex: what OPC UA tools show as the thumbprint."""
    return hashlib.sha1(cert.public_bytes(serialization.Encoding.DER)).hexdigest().upper()


def common_name(cert: x509.Certificate) -> str:
    names = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    return str(names[0].value) if names else "unnamed"


def application_uris(cert: x509.Certificate) -> list[str]:
    try:
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName)
    except x509.ExtensionNotFound:
        return []
    return list(san.value.get_values_for_type(x509.UniformResourceIdentifier))


# --- the server's own certificate ------------------------------------------------------------------


def ensure_certificate(pki: Pki, application_uri: str, name: str, hosts: Iterable[str]) -> x509.Certificate:
    """Load own/cert.der + own/key.pem, or generate them (first start, expired, or another URI). Blocking."""
    pki.create()
    reason = _unusable(pki, application_uri)
    if reason is None:
        return x509.load_der_x509_certificate(pki.cert.read_bytes())
    if pki.cert.exists() or pki.key.exists():
        stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
        for path in (pki.cert, pki.key):
            if path.exists():
                path.replace(path.with_name(f"{path.name}.{stamp}.old"))
        log.warning(
            "OPC UA server certificate %s: %s; generated a new one (clients must trust it again)",
            pki.cert,
            reason,
        )
    key = cert_gen.generate_private_key()
    names: list[x509.GeneralName] = [x509.UniformResourceIdentifier(application_uri)]
    for host in dict.fromkeys(h for h in hosts if h):
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            names.append(x509.DNSName(host))
    cert = cert_gen.generate_self_signed_app_certificate(
        key,
        name,
        {},
        names,
        [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH],
        days=CERT_DAYS,
    )
    _write_private(pki.key, cert_gen.dump_private_key_as_pem(key))
    pki.cert.write_bytes(cert.public_bytes(serialization.Encoding.DER))
    log.info(
        "OPC UA server certificate generated: %s (thumbprint %s, valid until %s)",
        pki.cert,
        thumbprint(cert),
        cert.not_valid_after_utc.date(),
    )
    return cert


def _unusable(pki: Pki, application_uri: str) -> str | None:
    if not pki.cert.exists() or not pki.key.exists():
        return "missing" if not pki.cert.exists() and not pki.key.exists() else "certificate or key missing"
    try:
        cert = x509.load_der_x509_certificate(pki.cert.read_bytes())
        # Readable is enough here (secure_server loads it the same way next).
        serialization.load_pem_private_key(
            pki.key.read_bytes(), password=None, unsafe_skip_rsa_key_validation=True
        )
    except (ValueError, TypeError, OSError) as exc:
        return f"unreadable ({exc})"
    if cert.not_valid_after_utc - RENEW_BEFORE < datetime.now(UTC):
        return f"expired on {cert.not_valid_after_utc.date()}"
    if application_uri not in application_uris(cert):
        return f"made for another application URI ({', '.join(application_uris(cert)) or 'none'})"
    return None


def _write_private(path: Path, data: bytes) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(data)


def certificate_hosts(endpoint_host: str) -> list[str]:
    """Names the server certificate carries: this host's name, the endpoint's host, localhost."""
    hosts = [socket.gethostname(), "localhost", "127.0.0.1"]
    if endpoint_host not in ("0.0.0.0", "::", ""):
        hosts.insert(0, endpoint_host)
    return hosts


# --- client certificates ---------------------------------------------------------------------------


class ClientCertificates:
    """asyncua's certificate validator for CreateSession: trusted/ decides, rejected/ records."""

    def __init__(self, pki: Pki) -> None:
        self.pki = pki
        self._checks = CertificateValidator(
            CertificateValidatorOptions.TIME_RANGE
            | CertificateValidatorOptions.URI
            | CertificateValidatorOptions.PEER_CLIENT
        )
        self._stamp: tuple[float, int] | None = None
        self._exact: set[bytes] = set()
        self._issuers: list[x509.Certificate] = []

    async def __call__(self, cert: x509.Certificate, app: ua.ApplicationDescription) -> None:
        try:
            await self._checks.validate(cert, app)
            self._reload()
            if not self._trusted(cert):
                raise ServiceError(ua.StatusCodes.BadCertificateUntrusted)
        except ServiceError as exc:
            await asyncio.to_thread(self._reject, cert, app, new_status_code(exc.code).name)
            raise

    def _trusted(self, cert: x509.Certificate) -> bool:
        if cert.public_bytes(serialization.Encoding.DER) in self._exact:
            return True
        for issuer in self._issuers:
            if issuer.subject != cert.issuer:
                continue
            try:
                cert.verify_directly_issued_by(issuer)
            except (ValueError, TypeError, InvalidSignature):  # wrong key type, bad signature
                continue
            return True
        return False

    def _reload(self) -> None:
        """Read trusted/ again when it changed (one stat per session otherwise)."""
        folder = self.pki.trusted
        try:
            st = folder.stat()
            stamp = (st.st_mtime, len(os.listdir(folder)))
        except OSError:
            stamp = (0.0, 0)
        if stamp == self._stamp:
            return
        self._stamp = stamp
        exact: set[bytes] = set()
        issuers: list[x509.Certificate] = []
        for path in sorted(folder.glob("*")) if folder.is_dir() else []:
            cert = _load_any(path)
            if cert is None:
                continue
            exact.add(cert.public_bytes(serialization.Encoding.DER))
            if _is_ca(cert):
                issuers.append(cert)
        self._exact, self._issuers = exact, issuers
        log.info("OPC UA trust list: %d certificate(s) in %s", len(exact), folder)

    def _reject(self, cert: x509.Certificate, app: ua.ApplicationDescription, status: str) -> None:
        thumb = thumbprint(cert)
        cn = common_name(cert)
        folder = self.pki.rejected
        target = folder / f"{_safe(cn)} [{thumb}].der"
        where = ""
        try:
            if not target.exists():
                if sum(1 for _ in folder.glob("*.der")) < MAX_REJECTED:
                    target.write_bytes(cert.public_bytes(serialization.Encoding.DER))
                    where = f"; saved as {target} (move it to {self.pki.trusted} to trust it)"
            else:
                where = f"; already in {target}"
        except OSError as exc:
            where = f"; cannot save it in {folder}: {exc.strerror or exc}"
        log.warning(
            "OPC UA client certificate refused (%s): CN=%s, application %s, thumbprint %s, valid %s to %s%s",
            status,
            cn,
            app.ApplicationUri,
            thumb,
            cert.not_valid_before_utc.date(),
            cert.not_valid_after_utc.date(),
            where,
        )


def _load_any(path: Path) -> x509.Certificate | None:
    if path.suffix.lower() not in (".der", ".pem", ".crt", ".cer"):
        return None
    try:
        data = path.read_bytes()
        if b"-----BEGIN CERTIFICATE-----" in data:
            return x509.load_pem_x509_certificate(data)
        return x509.load_der_x509_certificate(data)
    except (OSError, ValueError) as exc:
        log.warning("OPC UA trust list: cannot read %s: %s", path, exc)
        return None


def _is_ca(cert: x509.Certificate) -> bool:
    try:
        return bool(cert.extensions.get_extension_for_class(x509.BasicConstraints).value.ca)
    except x509.ExtensionNotFound:
        return False


def _safe(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.@\- ]", "_", text)[:64] or "unnamed"


# --- the trust list as an administrator sees it (the web console's TrustPort) ----------------------


class TrustList:
    """The certificates in trusted/ and rejected/, and moving one from either to the other.

    Moving a file into trusted/ is all that trusting takes: `ClientCertificates`
    re-reads the folder when it changes, so the client's next attempt succeeds.
    Names are plain file names of one of the two folders: nothing else can be moved.
    """

    def __init__(self, pki: Pki) -> None:
        self.pki = pki

    def certificates(self) -> list[dict[str, Any]]:
        out: list[dict[str, Any]] = []
        for state, folder in (("rejected", self.pki.rejected), ("trusted", self.pki.trusted)):
            for path in sorted(folder.glob("*")) if folder.is_dir() else []:
                cert = _load_any(path)
                if cert is None:
                    continue
                out.append(
                    {
                        "name": path.name,
                        "state": state,
                        "subject": common_name(cert),
                        "thumbprint": thumbprint(cert),
                        "application_uris": application_uris(cert),
                        "not_before": cert.not_valid_before_utc,
                        "not_after": cert.not_valid_after_utc,
                        "ca": _is_ca(cert),
                    }
                )
        return out

    def trust(self, name: str) -> dict[str, Any]:
        return self._move(name, self.pki.rejected, self.pki.trusted)

    def reject(self, name: str) -> dict[str, Any]:
        return self._move(name, self.pki.trusted, self.pki.rejected)

    def _move(self, name: str, source: Path, target: Path) -> dict[str, Any]:
        path = source / name
        if Path(name).name != name or name.startswith(".") or not path.is_file() or _load_any(path) is None:
            raise NotFound(f"no certificate {name!r} in {source.name}/")
        target.mkdir(parents=True, exist_ok=True)
        os.replace(path, target / name)
        log.warning("OPC UA trust list: %s moved from %s/ to %s/", name, source.name, target.name)
        return next(c for c in self.certificates() if c["name"] == name and c["state"] == target.name)


# --- applying it to the server ---------------------------------------------------------------------


async def secure_server(
    server: Any, endpoints: Iterable[str], pki: Pki, application_uri: str, name: str, endpoint_host: str
) -> ClientCertificates | None:
    """Offer `endpoints` on `server` (an asyncua Server, before start); certificate and trust list when
    any endpoint is secure. Returns the client-certificate check (None for None-only servers)."""
    names = list(endpoints)
    server.set_security_policy([POLICY_TYPES[n] for n in names])
    if not any(is_secure(n) for n in names):
        return None
    try:
        await asyncio.to_thread(
            ensure_certificate, pki, application_uri, name, certificate_hosts(endpoint_host)
        )
        await server.load_certificate(str(pki.cert))
        # What Server.load_private_key sets, without its check of the key's numbers: 0.1-0.4 s of the event
        # loop at every start (holding the GIL even in a thread), while the sources are already connecting
        # (app.py). The key is the gateway's own (generated here, in a folder only its user may write);
        # ensure_certificate has just read it the same way.
        server.iserver.private_key = serialization.load_pem_private_key(
            pki.key.read_bytes(), password=None, unsafe_skip_rsa_key_validation=True
        )
    except OSError as exc:
        raise SinkError(f"OPC UA server certificate in {pki.own}: {exc.strerror or exc}") from None
    check = ClientCertificates(pki)
    server.set_certificate_validator(check)
    return check

"""An FTP upload to the gateway's inbox, the robust way: `<name>.part`, then a rename that submits it.

Used by `cnc-gateway jobs submit`. Python's ftplib (blocking, which suits a
command), with implicit FTPS when the inbox serves it. The rename's reply is
the gateway's verdict: `250 J000042 queued for laser-sim` or `550 J000043 rejected: …`.
"""

from __future__ import annotations

import ftplib
import socket
import ssl
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gateway.errors import GatewayError

BLOCK = 64 * 1024


class UploadFailed(GatewayError):
    """The upload did not reach the point where the gateway judged it (connection, login, refusal)."""


class ImplicitFTPS(ftplib.FTP_TLS):
    """FTPS with TLS from the first byte (ftplib only does AUTH TLS by itself)."""

    def connect(
        self, host: str = "", port: int = 0, timeout: float = -999, source_address: Any = None
    ) -> str:
        if host:
            self.host = host
        if port > 0:
            self.port = port
        if timeout != -999:
            self.timeout = timeout
        raw = socket.create_connection((self.host, self.port), self.timeout)
        self.sock = self.context.wrap_socket(raw, server_hostname=self.host)
        self.af = self.sock.family
        self.file = self.sock.makefile("r", encoding=self.encoding)
        self.welcome = self.getresp()
        return self.welcome


def upload(
    host: str,
    port: int,
    user: str,
    password: str,
    machine: str,
    source: Path,
    name: str,
    *,
    priority: int | None = None,
    tls: bool = False,
    verify: bool = True,
    timeout: float = 30.0,
    progress: Callable[[int], None] | None = None,
) -> tuple[bool, str]:
    """(accepted, the gateway's reply). Raises UploadFailed when it never got that far."""
    if tls:
        context = ssl.create_default_context()
        if not verify:
            context.check_hostname = False
            context.verify_mode = ssl.CERT_NONE
        ftp: ftplib.FTP = ImplicitFTPS(context=context, timeout=timeout)
    else:
        ftp = ftplib.FTP(timeout=timeout)
    sent = 0

    def count(block: bytes) -> None:
        nonlocal sent
        sent += len(block)
        if progress is not None:
            progress(sent)

    temp = name + ".part"
    try:
        ftp.connect(host, port)
        ftp.login(user, password)
        if isinstance(ftp, ImplicitFTPS):
            ftp.prot_p()
        ftp.cwd(f"/{machine}")
        if priority is not None:
            ftp.sendcmd(f"SITE PRIORITY {priority}")
        with source.open("rb") as f:
            ftp.storbinary(f"STOR {temp}", f, BLOCK, count)
        ftp.sendcmd(f"RNFR {temp}")
        try:
            reply = ftp.sendcmd(f"RNTO {name}")
        except ftplib.error_perm as exc:
            return False, _text(exc)
        return True, _text(reply)
    except ftplib.all_errors as exc:
        raise UploadFailed(f"{host}:{port}: {str(exc).strip() or type(exc).__name__}") from None
    finally:
        try:
            ftp.quit()
        except ftplib.all_errors:
            ftp.close()


def _text(reply: object) -> str:
    """'250 J000042 queued' -> 'J000042 queued'."""
    text = str(reply).strip()
    return text[4:] if len(text) > 4 and text[:3].isdigit() and text[3] in " -" else text

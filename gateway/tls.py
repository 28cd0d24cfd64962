"""A server's TLS context from a certificate and key in the state directory (FTP inbox, web console).

One place, so that every door that serves TLS names its files, and what to do when
they are missing, the same way.
"""

from __future__ import annotations

import ssl
from pathlib import Path

from gateway.errors import SinkError


def server_context(state_dir: Path, cert: str, key: str, what: str) -> ssl.SSLContext:
    """The server context for `what` ("FTP inbox", …); SinkError says which file is missing or wrong."""
    cert_path, key_path = state_dir / cert, state_dir / key
    for path in (cert_path, key_path):
        if not path.is_file():
            raise SinkError(
                f"{what} TLS: {path} does not exist; create it, e.g. "
                "`openssl req -x509 -newkey rsa:2048 -nodes -days 3650 -subj /CN=cnc-gateway "
                f"-keyout {key_path} -out {cert_path}`"
            )
    context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    try:
        context.load_cert_chain(cert_path, key_path)
    except (ssl.SSLError, OSError) as exc:
        raise SinkError(f"{what} TLS: cannot load {cert_path} / {key_path}: {exc}") from None
    return context

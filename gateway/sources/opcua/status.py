"""OPC UA status codes and errors, as the names and short reasons users read.

Variables carry a StatusCode *name* ("BadNodeIdUnknown"), so every sink can show
the real code; connection problems become one short human reason ("connection
refused", "server shut down") for the status line and the log. Uses asyncua's
status table only, no client API and no I/O.
"""

from __future__ import annotations

import socket
from functools import lru_cache

from asyncua.ua import status_codes
from asyncua.ua.uaerrors import UaError, UaStatusCodeError


@lru_cache(maxsize=512)
def status_name(code: int) -> str:
    """The StatusCode's name ("Good", "BadNodeIdUnknown", …), ignoring the info bits."""
    return status_codes.get_name_and_doc(code & 0xFFFF0000)[0]


@lru_cache(maxsize=512)
def status_doc(code: int) -> str:
    return status_codes.get_name_and_doc(code & 0xFFFF0000)[1]


_LOGIN_REFUSED = frozenset(
    {"BadUserAccessDenied", "BadIdentityTokenInvalid", "BadIdentityTokenRejected", "BadUserSignatureInvalid"}
)


def describe_error(exc: BaseException) -> tuple[str, str, bool]:
    """(status for the variables, short human reason, whether it is an expected controller problem)."""
    if isinstance(exc, UaStatusCodeError):
        name = status_name(exc.code)
        if name in ("BadServerHalted", "BadShutdown"):
            return "BadNotConnected", "server shut down", True
        if name in _LOGIN_REFUSED:
            return "BadNotConnected", f"login refused ({name})", True
        if name in ("BadTimeout", "BadRequestTimeout"):
            return "BadCommunicationError", "timeout", True
        if "Certificate" in name or "Security" in name:
            return "BadNotConnected", f"security check failed ({name})", True
        return "BadCommunicationError", f"controller answered {name}", True
    if isinstance(exc, ConnectionRefusedError):
        return "BadNotConnected", "connection refused", True
    if isinstance(exc, TimeoutError):
        return "BadCommunicationError", "timeout", True
    if isinstance(exc, socket.gaierror):
        return "BadNotConnected", "host not found", True
    if isinstance(exc, ConnectionResetError):
        return "BadNotConnected", "connection reset", True
    if isinstance(exc, ConnectionError):
        return "BadNotConnected", "connection closed by the server", True
    if isinstance(exc, OSError):
        return "BadNotConnected", f"network error: {exc.strerror or exc}", True
    if isinstance(exc, UaError):
        return "BadCommunicationError", f"OPC UA error: {exc}", True
    return "BadCommunicationError", f"unexpected error: {type(exc).__name__}: {exc}", False

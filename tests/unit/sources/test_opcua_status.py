import socket

import pytest
from asyncua.ua import StatusCodes
from asyncua.ua.uaerrors import UaStatusCodeError

from gateway.sources.opcua.status import describe_error, status_name


@pytest.mark.parametrize(
    ("code", "name"),
    [
        (0x00000000, "Good"),
        (StatusCodes.BadNodeIdUnknown, "BadNodeIdUnknown"),
        (StatusCodes.BadAttributeIdInvalid, "BadAttributeIdInvalid"),
        (StatusCodes.BadNotWritable, "BadNotWritable"),
        (StatusCodes.UncertainNoCommunicationLastUsableValue, "UncertainNoCommunicationLastUsableValue"),
        (0x80340480, "BadNodeIdUnknown"),  # info bits (overflow, limits) do not change the name
        (0x00000480, "Good"),
        (0x80FF0000, "Bad"),  # not a code we know: its severity is still readable
        (0x40FF0000, "Uncertain"),
    ],
)
def test_status_names_follow_the_code_ignoring_info_bits(code: int, name: str) -> None:
    assert status_name(code) == name


@pytest.mark.parametrize(
    ("exc", "status", "reason"),
    [
        (ConnectionRefusedError(111, "Connection refused"), "BadNotConnected", "connection refused"),
        (TimeoutError(), "BadCommunicationError", "timeout"),
        (ConnectionError("transport lost"), "BadNotConnected", "connection closed by the server"),
        (ConnectionResetError(104, "reset"), "BadNotConnected", "connection reset"),
        (socket.gaierror(-2, "Name or service not known"), "BadNotConnected", "host not found"),
        (OSError(113, "No route to host"), "BadNotConnected", "network error: No route to host"),
        (UaStatusCodeError(StatusCodes.BadServerHalted), "BadNotConnected", "server shut down"),
        (
            UaStatusCodeError(StatusCodes.BadUserAccessDenied),
            "BadNotConnected",
            "login refused (BadUserAccessDenied)",
        ),
        (
            UaStatusCodeError(StatusCodes.BadSecurityChecksFailed),
            "BadNotConnected",
            "security check failed (BadSecurityChecksFailed)",
        ),
        (
            UaStatusCodeError(StatusCodes.BadSessionIdInvalid),
            "BadCommunicationError",
            "controller answered BadSessionIdInvalid",
        ),
    ],
)
def test_errors_become_a_status_and_a_short_reason(exc: BaseException, status: str, reason: str) -> None:
    assert describe_error(exc) == (status, reason, True)


def test_a_bug_is_reported_as_unexpected() -> None:
    _status, reason, expected = describe_error(KeyError("x"))
    assert not expected
    assert reason.startswith("unexpected error: KeyError")

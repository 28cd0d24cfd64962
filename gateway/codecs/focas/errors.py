"""FOCAS return codes (what a controller answers per command) and the codec's own error."""

from __future__ import annotations

from gateway.errors import CodecError

EW_OK = 0
#: The codes a FOCAS library returns, by number: the positive ones come from the controller in a
#: reply's error field, the negative ones are the library's (and this gateway's) own.
RETURN_CODES: dict[int, tuple[str, str]] = {
    -17: ("EW_PROTOCOL", "protocol error"),
    -16: ("EW_SOCKET", "socket error (no session: the controller's session limit may be reached)"),
    -15: ("EW_NODLL", "no library for this controller"),
    -11: ("EW_BUS", "bus error"),
    -10: ("EW_SYSTEM2", "system error"),
    -9: ("EW_HSSB", "HSSB communication error"),
    -8: ("EW_HANDLE", "invalid session"),
    -7: ("EW_VERSION", "version mismatch between the CNC and the client"),
    -6: ("EW_UNEXP", "unexpected error"),
    -5: ("EW_SYSTEM", "system error"),
    -4: ("EW_PARITY", "shared RAM parity error"),
    -3: ("EW_MMCSYS", "FANUC drivers are not installed"),
    -2: ("EW_RESET", "reset or stop occurred"),
    -1: ("EW_BUSY", "the controller is busy"),
    0: ("EW_OK", "no error"),
    1: ("EW_FUNC", "function not available on this controller"),
    2: ("EW_LENGTH", "data block length error"),
    3: ("EW_NUMBER", "number out of range"),
    4: ("EW_ATTRIB", "data attribute error"),
    5: ("EW_DATA", "data error"),
    6: ("EW_NOOPT", "the option is not fitted"),
    7: ("EW_PROT", "write protected"),
    8: ("EW_OVRFLOW", "memory overflow"),
    9: ("EW_PARAM", "CNC parameter error"),
    10: ("EW_BUFFER", "buffer empty or full"),
    11: ("EW_PATH", "path number error"),
    12: ("EW_MODE", "the controller is in the wrong mode"),
    13: ("EW_REJECT", "execution rejected"),
    14: ("EW_DTSRVR", "data server error"),
    15: ("EW_ALARM", "an alarm is active"),
    16: ("EW_STOP", "the controller is stopped"),
    17: ("EW_PASSWD", "protected by the state of the data protection"),
}
EW_BUSY = -1
EW_SOCKET = -16
EW_PROTOCOL = -17
EW_FUNC = 1
EW_LENGTH = 2
EW_NUMBER = 3
EW_DATA = 5
EW_NOOPT = 6
EW_PROT = 7
EW_OVRFLOW = 8
EW_MODE = 12
EW_REJECT = 13


def describe(code: int) -> str:
    """`EW_NUMBER (3): number out of range`, or `error 42` for a code nobody documented."""
    known = RETURN_CODES.get(code)
    if known is None:
        return f"error {code}"
    return f"{known[0]} ({code}): {known[1]}"


class FocasError(CodecError):
    """Bytes that are not FOCAS, or a reply carrying a controller's error code (`code`, 0 if none)."""

    def __init__(self, reason: str, *, code: int = EW_PROTOCOL) -> None:
        super().__init__(reason)
        self.reason = reason
        self.code = code

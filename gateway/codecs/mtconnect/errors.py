"""Errors of the MTConnect codecs: what an agent answers with an MTConnectError document.

A `RequestError` carries one of the error codes of the MTConnect 2.4 Error schema
(`ErrorCode`), the text for the document, and the HTTP status the agent should use.
Every one is a `gateway.errors.CodecError` (hence a ValueError), so callers that only
care about "bad input" catch that.
"""

from __future__ import annotations

from enum import Enum

from gateway.errors import CodecError


class ErrorCode(str, Enum):
    """The errorCode values of MTConnectError_2.4.xsd, no more.

    MTConnect 1.x called INVALID_PATH "INVALID_XPATH"; the 2.4 schema only knows
    INVALID_PATH, so that is what a refused `path=` gets.
    """

    UNAUTHORIZED = "UNAUTHORIZED"
    NO_DEVICE = "NO_DEVICE"
    OUT_OF_RANGE = "OUT_OF_RANGE"
    TOO_MANY = "TOO_MANY"
    INVALID_URI = "INVALID_URI"
    INVALID_REQUEST = "INVALID_REQUEST"
    INTERNAL_ERROR = "INTERNAL_ERROR"
    INVALID_PATH = "INVALID_PATH"
    UNSUPPORTED = "UNSUPPORTED"
    ASSET_NOT_FOUND = "ASSET_NOT_FOUND"


# The HTTP status an agent answers with, per code (the reference agent's choices).
HTTP_STATUS: dict[ErrorCode, int] = {
    ErrorCode.UNAUTHORIZED: 401,
    ErrorCode.NO_DEVICE: 404,
    ErrorCode.OUT_OF_RANGE: 400,
    ErrorCode.TOO_MANY: 400,
    ErrorCode.INVALID_URI: 400,
    ErrorCode.INVALID_REQUEST: 400,
    ErrorCode.INTERNAL_ERROR: 500,
    ErrorCode.INVALID_PATH: 400,
    ErrorCode.UNSUPPORTED: 400,
    ErrorCode.ASSET_NOT_FOUND: 404,
}


class MTConnectCodecError(CodecError):
    """Base of the MTConnect codec errors."""


class RequestError(MTConnectCodecError):
    """A request the agent refuses; becomes one Error of an MTConnectError document."""

    def __init__(self, code: ErrorCode, message: str) -> None:
        super().__init__(message)
        self.code = code
        self.message = message

    @property
    def http_status(self) -> int:
        return HTTP_STATUS[self.code]

    def __str__(self) -> str:
        return f"{self.code.value}: {self.message}"


class OutOfRange(RequestError):
    """A sequence number or count outside what the buffer can answer."""

    def __init__(self, parameter: str, value: int, minimum: int, maximum: int, message: str) -> None:
        super().__init__(ErrorCode.OUT_OF_RANGE, message)
        self.parameter = parameter
        self.value = value
        self.minimum = minimum
        self.maximum = maximum


class InvalidPath(RequestError):
    """A `path=` expression outside the supported XPath subset, or one that selects nothing."""

    def __init__(self, message: str) -> None:
        super().__init__(ErrorCode.INVALID_PATH, message)


class ModelError(MTConnectCodecError):
    """A device model that cannot be rendered as a valid MTConnectDevices document."""


class ValueRejected(MTConnectCodecError):
    """A value that the data item's observation element cannot hold (a word for a SAMPLE, ...)."""

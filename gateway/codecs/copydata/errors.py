"""Errors of the COPYDATA codec: one class per way a frame or a value can be wrong.

Every error is a `CopydataError` (a `gateway.errors.CodecError`, hence also a
ValueError) with a stable `kind` string, for logs and metrics, and an `offset`:
the byte position of the fault in the input of the call that raised it (lpData
for `decode_lpdata`, the value's bytes for `decode_value`, the whole stream for
`FrameDecoder`), or None where no byte is at fault (encoding a Python value).
Callers that care only about "bad input" catch `CopydataError`; tests and
receivers that want to tell cases apart catch the subclass.
"""

from __future__ import annotations

from gateway.codecs.copydata.frame import Frame
from gateway.errors import CodecError


class CopydataError(CodecError):
    """A COPYDATA frame or value is malformed, or a value cannot be encoded."""

    kind = "copydata"

    def __init__(self, message: str, *, offset: int | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.offset = offset
        # Frames a FrameDecoder completed in the same feed() before it met this fault.
        self.frames: tuple[Frame, ...] = ()

    def __str__(self) -> str:
        if self.offset is None:
            return self.message
        return f"{self.message} (at byte {self.offset})"

    def _shift(self, delta: int, context: str = "") -> CopydataError:
        """Re-base the offset onto an enclosing input and name what was being decoded.

        Used when an inner call (a value inside lpData, lpData inside a stream)
        raised: the caller knows where the inner input started.
        """
        if self.offset is not None:
            self.offset += delta
        if context:
            self.message = f"{context}: {self.message}"
            self.args = (self.message,)
        return self


# --- decoding: framing ---------------------------------------------------------------------


class TruncatedHeader(CopydataError):
    """Fewer bytes remain than an id and length field (or a String[] element's length) need."""

    kind = "truncated_header"


class LengthOverrun(CopydataError):
    """A length field points past the end of the bytes that contain it."""

    kind = "length_overrun"


class TruncatedFrame(CopydataError):
    """The stream or datagram ended in the middle of a frame."""

    kind = "truncated_frame"


class TrailingBytes(CopydataError):
    """A datagram holds more bytes than its cbData announces."""

    kind = "trailing_bytes"


class UnknownDwData(CopydataError):
    """dwData is neither 1 (one variable) nor 2 (several variables)."""

    kind = "unknown_dwdata"


class FrameTooLarge(CopydataError):
    """cbData is over the layout's max_cbdata (raised by decoders and encoders alike)."""

    kind = "frame_too_large"


class ItemCountMismatch(CopydataError):
    """A dwData=1 frame without exactly one item, or a dwData=2 frame without any."""

    kind = "item_count"


class DecoderFailed(CopydataError):
    """A FrameDecoder was fed again after an error: its stream is desynchronised for good."""

    kind = "decoder_failed"


# --- decoding: values ----------------------------------------------------------------------


class UnknownId(CopydataError):
    """An item's variable id is not in the variable table."""

    kind = "unknown_id"


class BadValue(CopydataError):
    """An item's bytes do not decode as the variable's declared type."""

    kind = "bad_value"


class WrongSize(BadValue):
    """The byte count does not fit the type (8 for a Double, a multiple of 4 for Int32[] ...)."""

    kind = "wrong_size"


class BadBoolean(BadValue):
    """A Boolean byte other than 0 or 1."""

    kind = "bad_boolean"


class BadText(BadValue):
    """String bytes that are not valid in the layout's encoding."""

    kind = "bad_text"


class BadFiletime(BadValue):
    """A FILETIME past the last instant Python's datetime can hold (9999-12-31)."""

    kind = "bad_filetime"


# --- encoding ------------------------------------------------------------------------------


class CopydataEncodeError(CopydataError):
    """A Python value, id or length that cannot be put into a frame."""

    kind = "encode"


class ValueTypeError(CopydataEncodeError):
    """The Python value is not of the kind the type needs (text for a Double, 1 for a Boolean)."""

    kind = "value_type"


class ValueOutOfRange(CopydataEncodeError):
    """The value does not fit the type: 300 as Byte, 1e39 as Float, a date before 1601."""

    kind = "value_range"


class Unencodable(CopydataEncodeError):
    """Text with a character the layout's encoding cannot represent."""

    kind = "unencodable_text"


class FieldOverflow(CopydataEncodeError):
    """An id or a length that does not fit its configured field width."""

    kind = "field_overflow"

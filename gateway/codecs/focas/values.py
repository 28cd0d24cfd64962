"""The data FOCAS functions carry: scaled numbers, sysinfo, statinfo, alarms, names, directories.

Numbers of axes, feeds, spindles and macros travel as 8 bytes: a signed 32-bit mantissa, a 16-bit
base (10; 2 seen too) and a 16-bit exponent, value = mantissa / base ** exponent; an exponent of
-1 (FF FF) marks a vacant macro (`<blank>` on the screen).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from gateway.codecs.focas.errors import FocasError

SCALED = struct.Struct(">ihh")
VACANT = b"\x00\x00\x00\x00\x00\x0a\xff\xff"
_INT32 = (-(2**31), 2**31 - 1)


def decode_scaled(data: bytes | memoryview, at: int = 0) -> float | None:
    """The number at `at`, or None when it is vacant; FocasError when it is not a FOCAS number."""
    if len(data) < at + 8:
        raise FocasError(f"a FOCAS number needs 8 bytes, {max(0, len(data) - at)} are there")
    mantissa: int
    base: int
    exponent: int
    mantissa, base, exponent = SCALED.unpack_from(data, at)
    if exponent == -1:
        return None
    if base not in (2, 10) or not 0 <= exponent <= 15:
        raise FocasError(f"base {base}, exponent {exponent} is not a FOCAS number")
    if exponent == 0:
        return float(mantissa)
    if base == 2:
        return mantissa / float(2**exponent)
    return round(mantissa / float(10**exponent), exponent)


def scaled_parts(value: float, max_decimals: int = 9) -> tuple[int, int]:
    """Mantissa and decimal exponent for `value` in 32 bits, with as many decimals as fit (up to 9)."""
    if not math.isfinite(value):
        raise ValueError(f"{value!r} cannot be a FOCAS number")
    for decimals in range(max_decimals, -1, -1):
        mantissa = round(value * 10**decimals)
        if _INT32[0] <= mantissa <= _INT32[1]:
            return mantissa, decimals
    raise ValueError(f"{value!r} is too large for a FOCAS number (32-bit mantissa)")


def encode_scaled(value: float | None, decimals: int | None = None) -> bytes:
    """8 bytes for `value` (None: vacant); `decimals` fixed (positions: the axis' increment) or best fit."""
    if value is None:
        return VACANT
    if decimals is None:
        mantissa, decimals = scaled_parts(value)
        # drop trailing zeros: 12.5 travels as 125 e1, as a controller sends it
        while decimals and mantissa % 10 == 0:
            mantissa //= 10
            decimals -= 1
    else:
        mantissa = round(value * 10**decimals)
        if not _INT32[0] <= mantissa <= _INT32[1]:
            raise ValueError(f"{value!r} does not fit a FOCAS number with {decimals} decimals")
    return SCALED.pack(mantissa, 10, decimals)


def decode_scaled_list(data: bytes, count: int | None = None) -> list[float | None]:
    if len(data) % 8:
        raise FocasError(f"{len(data)} bytes is not a whole number of 8-byte FOCAS numbers")
    n = len(data) // 8 if count is None else min(count, len(data) // 8)
    return [decode_scaled(data, 8 * i) for i in range(n)]


def _text(raw: bytes) -> str:
    return raw.split(b"\x00", 1)[0].decode("ascii", errors="replace").strip()


def _fixed(text: str, size: int) -> bytes:
    raw = text.encode("ascii", errors="replace")[:size]
    return raw + b"\x00" * (size - len(raw))


_SYSINFO = struct.Struct(">hh2s2s4s4s2s")


@dataclass(frozen=True, slots=True)
class SysInfo:
    """cnc_sysinfo: what controller this is."""

    addinfo: int
    max_axis: int
    cnc_type: str  # " 0" 0i, "30", "31", "32", "16", ...
    mt_type: str  # " M" mill, " T" lathe, ...
    series: str
    version: str
    axes: str  # controlled axes, as two characters: " 3"

    @classmethod
    def decode(cls, data: bytes) -> SysInfo:
        if len(data) < _SYSINFO.size:
            raise FocasError(f"sysinfo is {_SYSINFO.size} bytes, not {len(data)}")
        addinfo, max_axis, cnc, mt, series, version, axes = _SYSINFO.unpack_from(data)
        return cls(addinfo, max_axis, _text(cnc), _text(mt), _text(series), _text(version), _text(axes))

    def encode(self) -> bytes:
        return _SYSINFO.pack(
            self.addinfo,
            self.max_axis,
            _fixed(self.cnc_type.rjust(2), 2),
            _fixed(self.mt_type.rjust(2), 2),
            _fixed(self.series, 4),
            _fixed(self.version, 4),
            _fixed(self.axes.rjust(2), 2),
        )

    @property
    def axis_count(self) -> int:
        try:
            return int(self.axes)
        except ValueError:
            return self.max_axis


_STATINFO = struct.Struct(">7h")
STAT_FIELDS = ("mode", "run", "motion", "mstb", "emergency", "alarm", "edit")


@dataclass(frozen=True, slots=True)
class StatInfo:
    """cnc_statinfo: mode (`aut`), run, motion, M/S/T/B, emergency, alarm, edit."""

    mode: int
    run: int
    motion: int
    mstb: int
    emergency: int
    alarm: int
    edit: int

    @classmethod
    def decode(cls, data: bytes) -> StatInfo:
        if len(data) < _STATINFO.size:
            raise FocasError(f"statinfo is {_STATINFO.size} bytes, not {len(data)}")
        return cls(*_STATINFO.unpack_from(data))

    def encode(self) -> bytes:
        return _STATINFO.pack(
            self.mode, self.run, self.motion, self.mstb, self.emergency, self.alarm, self.edit
        )


#: cnc_statinfo's `aut` and `run`, as a 0i-F/30i reports them.
MODES = {0: "MDI", 1: "MEM", 2: "****", 3: "EDIT", 4: "HND", 5: "JOG", 6: "TJOG", 7: "THND", 8: "INC",
         9: "REF", 10: "RMT"}  # fmt: skip
RUN_STATES = {0: "****", 1: "STOP", 2: "HOLD", 3: "STRT", 4: "MSTR"}

_ALARM = struct.Struct(">iiii")
ALARM_TEXT = 64
ALARM_ENTRY = _ALARM.size + ALARM_TEXT  # 80


@dataclass(frozen=True, slots=True)
class AlarmEntry:
    """One active alarm (cnc_rdalmmsg): number, type (the class: 0 SW, 1 PW, 2 IO, 4 OT, ...), axis."""

    number: int
    type: int
    axis: int
    message: str

    def encode(self) -> bytes:
        raw = self.message.encode("ascii", errors="replace")[:ALARM_TEXT]
        return (
            _ALARM.pack(self.number, self.type, self.axis, len(raw)) + raw + b"\x00" * (ALARM_TEXT - len(raw))
        )


def decode_alarms(data: bytes) -> list[AlarmEntry]:
    if len(data) % ALARM_ENTRY:
        raise FocasError(f"{len(data)} bytes of alarms is not a whole number of {ALARM_ENTRY}-byte entries")
    out = []
    for at in range(0, len(data), ALARM_ENTRY):
        number, kind, axis, size = _ALARM.unpack_from(data, at)
        if not 0 <= size <= ALARM_TEXT:
            raise FocasError(f"an alarm message says it is {size} bytes (at most {ALARM_TEXT})")
        text = data[at + _ALARM.size : at + _ALARM.size + size]
        out.append(AlarmEntry(number, kind, axis, text.decode("ascii", errors="replace").rstrip("\x00 ")))
    return out


#: Alarm types (cnc_rdalmmsg), as the screens name them.
ALARM_TYPES = {0: "SW", 1: "PW", 2: "IO", 3: "PS", 4: "OT", 5: "OH", 6: "SV", 7: "SR", 8: "MC", 9: "SP",
               10: "DS", 11: "IE", 12: "BG", 13: "SN", 15: "EX", 19: "PC"}  # fmt: skip

_NAMED_PROGRAM = struct.Struct(">i36s")


def decode_program_name(data: bytes) -> tuple[int, str]:
    """cnc_exeprgname: the running program's O-number and name."""
    if len(data) < _NAMED_PROGRAM.size:
        raise FocasError(f"a program name answer is {_NAMED_PROGRAM.size} bytes, not {len(data)}")
    number, name = _NAMED_PROGRAM.unpack_from(data)
    return number, _text(name)


def encode_program_name(number: int, name: str) -> bytes:
    return _NAMED_PROGRAM.pack(number, _fixed(name, 36))


def decode_axis_names(data: bytes) -> list[str]:
    """cnc_rdaxisname: 4 bytes per axis, the name and its suffix."""
    if len(data) % 4:
        raise FocasError(f"{len(data)} bytes of axis names is not a whole number of 4-byte names")
    names = []
    for at in range(0, len(data), 4):
        name = data[at : at + 2].split(b"\x00", 1)[0].decode("ascii", errors="replace").strip()
        names.append(name)
    return names


def encode_axis_names(names: list[str]) -> bytes:
    return b"".join(_fixed(n, 2) + b"\x00\x00" for n in names)


_DIR_ENTRY = struct.Struct(">h6H6sII36s52s12s")
DIR_ENTRY = _DIR_ENTRY.size  # 128
PATH_FIELD = 256


@dataclass(frozen=True, slots=True)
class DirEntry:
    """One entry of a program folder (cnc_rddir on 30i-series): a folder or a file."""

    name: str
    is_file: bool
    size: int = 0
    stamp: tuple[int, int, int, int, int, int] = (2000, 1, 1, 0, 0, 0)
    comment: str = ""

    def encode(self) -> bytes:
        return _DIR_ENTRY.pack(
            1 if self.is_file else 0, *self.stamp, bytes(6), self.size, 0,
            _fixed(self.name, 36), _fixed(self.comment, 52), bytes(12),
        )  # fmt: skip


def decode_dir(data: bytes) -> list[DirEntry]:
    if len(data) % DIR_ENTRY:
        raise FocasError(
            f"{len(data)} bytes of folder entries is not a whole number of {DIR_ENTRY}-byte ones"
        )
    out = []
    for at in range(0, len(data), DIR_ENTRY):
        kind, y, mo, d, h, mi, s, _, size, _, name, comment, _ = _DIR_ENTRY.unpack_from(data, at)
        out.append(DirEntry(_text(name), kind == 1, size, (y, mo, d, h, mi, s), _text(comment)))
    return out


def path_field(text: str) -> bytes:
    """A name or folder as the 256-byte, NUL-padded field the file functions take."""
    raw = text.encode("ascii")
    if len(raw) >= PATH_FIELD or b"\x00" in raw:
        raise ValueError(f"{text!r} does not fit a FOCAS path ({PATH_FIELD - 1} ASCII characters)")
    return raw + b"\x00" * (PATH_FIELD - len(raw))


def read_path_field(data: bytes) -> str:
    return data[:PATH_FIELD].split(b"\x00", 1)[0].decode("ascii", errors="replace")


_PARAM_HEAD = struct.Struct(">ihh")


def decode_numbered(data: bytes, slots: int) -> list[tuple[int, int, int, list[int]]]:
    """Parameters and diagnostics (cnc_rdparam, cnc_diagnoss): per number, its axis field, its type and
    `slots` 32-bit values (one per axis, or the value in the first)."""
    stride = _PARAM_HEAD.size + 4 * slots
    if slots <= 0 or len(data) % stride:
        raise FocasError(f"{len(data)} bytes is not a whole number of {stride}-byte parameter entries")
    out = []
    for at in range(0, len(data), stride):
        number, axis, kind = _PARAM_HEAD.unpack_from(data, at)
        values = list(struct.unpack_from(f">{slots}i", data, at + _PARAM_HEAD.size))
        out.append((number, axis, kind, values))
    return out


def encode_numbered(number: int, axis: int, kind: int, values: list[int], slots: int) -> bytes:
    padded = (values + [0] * slots)[:slots]
    return _PARAM_HEAD.pack(number, axis, kind) + struct.pack(f">{slots}i", *padded)

"""`FocasCnc`: what the simulated laser answers to each FOCAS command. Pure: commands in, replies out.

It reads the machine model (positions, feed, program, alarms) and keeps what a Fanuc keeps beside
it: common macros (#100-#199, #500-#999), PMC areas (the override and cycle-start signals wired as a
ladder would: G12 feed override, G7.2 cycle start, G8.7 external reset; F0.7 automatic operation,
F1.0 alarm), a few parameters and diagnostics, and the program folder //CNC_MEM/USER/PATH1/ (the
simulator's program store).
"""

from __future__ import annotations

import logging
import struct
import time
from dataclasses import dataclass, field

from gateway.codecs.focas import functions as fn
from gateway.codecs.focas.commands import PMC, Command, Reply
from gateway.codecs.focas.errors import EW_DATA, EW_FUNC, EW_LENGTH, EW_MODE, EW_NUMBER, EW_PROT, EW_REJECT
from gateway.codecs.focas.values import (
    AlarmEntry,
    DirEntry,
    StatInfo,
    SysInfo,
    decode_scaled,
    encode_axis_names,
    encode_numbered,
    encode_program_name,
    encode_scaled,
    path_field,
    read_path_field,
)
from gateway.errors import InvalidArgument, InvalidState, RequestError
from simulator.alarms import SOFT_LIMIT, Severity
from simulator.errors import ProgramNotFound
from simulator.machine import Machine, MachineState, Mode

log = logging.getLogger("simulator.focas")

FOLDER = "//CNC_MEM/USER/PATH1/"
MAX_AXIS = 8
MACRO_WRITABLE = ((1, 33), (100, 199), (500, 999), (3901, 3902))
PMC_SIZE = 10_000
PMC_READ_ONLY = ("F", "X")  # written by the CNC and the machine, not by a client
MAX_RANGE = 1000  # macros, PMC bytes or parameters per command
MODE_AUT = {Mode.AUTO: 1, Mode.MANUAL: 5, Mode.MDA: 0}  # MEM, JOG, MDI
RUN = {MachineState.IDLE: 0, MachineState.RUNNING: 3, MachineState.PAUSED: 2, MachineState.ALARM: 1}


class _Refused(Exception):
    def __init__(self, code: int) -> None:
        self.code = code


@dataclass
class FocasCnc:
    """One controller's FOCAS state beside the machine model; `answer` serves one command."""

    machine: Machine
    sysinfo: SysInfo = field(default_factory=lambda: SysInfo(0, MAX_AXIS, "31", "M", "G4A1", "14.0", "3"))
    macros: dict[int, float | None] = field(default_factory=dict)
    pmc: dict[str, bytearray] = field(default_factory=lambda: {a: bytearray(PMC_SIZE) for a in fn.PMC_AREAS})
    params: dict[int, int] = field(default_factory=lambda: {6711: 0, 6713: 0, 3216: 1})
    required_parts: float = 0.0
    commands: int = 0  # served, for the bench's count of requests
    _start_signal: bool = False

    def __post_init__(self) -> None:
        for n in range(500, 510):
            self.macros[n] = 0.0
        self.pmc["G"][30] = 100  # spindle override 100 %
        self.pmc["G"][12] = 255 - self.machine.override

    # --- one command ------------------------------------------------------------------------

    def answer(self, cmd: Command) -> Reply:
        self.commands += 1
        try:
            data = self._serve(cmd)
        except _Refused as exc:
            return Reply(cmd.function, exc.code, b"", cmd.device, cmd.path)
        except RequestError as exc:
            log.debug("FOCAS command %#x refused: %s", cmd.function, exc.reason)
            code = (
                EW_MODE
                if isinstance(exc, InvalidState)
                else EW_DATA
                if isinstance(exc, InvalidArgument)
                else EW_REJECT
            )
            return Reply(cmd.function, code, b"", cmd.device, cmd.path)
        except (ValueError, struct.error) as exc:
            log.debug("FOCAS command %#x: bad data: %s", cmd.function, exc)
            return Reply(cmd.function, EW_DATA, b"", cmd.device, cmd.path)
        return Reply(cmd.function, 0, data, cmd.device, cmd.path)

    def _serve(self, cmd: Command) -> bytes:
        if cmd.device == PMC:
            if cmd.function == fn.PMC_READ:
                return self._pmc_read(cmd.args)
            if cmd.function == fn.PMC_WRITE:
                self._pmc_write(cmd.args, cmd.data)
                return b""
            raise _Refused(EW_FUNC)
        if cmd.device != 1:
            raise _Refused(EW_FUNC)
        m = self.machine
        f, a = cmd.function, cmd.args
        if f == fn.SYSINFO:
            return self.sysinfo.encode()
        if f == fn.STATINFO:
            return self.statinfo().encode()
        if f == fn.AXIS_NAMES:
            return encode_axis_names([axis.name for axis in m.axes])
        if f == fn.POSITION:
            return self._positions(a[0], a[1])
        if f == fn.ACTUAL_FEED:
            return encode_scaled(round(m.feed_rate), 0)
        if f == fn.ACTUAL_SPINDLE:  # a laser's S is its power
            return encode_scaled(round(m.laser.power_act), 0)
        if f == fn.PROGRAM_NUMBER:
            number = program_number(m.program.name)
            return struct.pack(">ii", number, number)
        if f == fn.PROGRAM_NAME:
            return encode_program_name(program_number(m.program.name), m.program.name)
        if f == fn.SEQUENCE_NUMBER:
            return struct.pack(">i", m.program.block)
        if f == fn.EXECUTING_BLOCK:
            text = m.program.block_text.encode("ascii", errors="replace")[: max(0, a[0])]
            return struct.pack(">i", m.program.block) + text
        if f == fn.MACRO_READ:
            return b"".join(encode_scaled(self.macro(n)) for n in self._range(a[0], a[1]))
        if f == fn.MACRO_READ_DOUBLE:
            return b"".join(struct.pack(">d", self.macro(n) or 0.0) for n in self._range(a[0], a[1]))
        if f == fn.MACRO_WRITE:
            self._macro_write(a[0], a[1], cmd.data)
            return b""
        if f == fn.MACRO_WRITE_DOUBLE:
            if len(cmd.data) != 8:
                raise _Refused(EW_LENGTH)
            self.set_macro(a[0], struct.unpack(">d", cmd.data)[0])
            return b""
        if f == fn.ALARM_MESSAGES:
            return b"".join(e.encode() for e in self.alarm_entries()[: max(0, a[1])])
        if f == fn.ALARM_STATUS:
            bits = 0
            for entry in self.alarm_entries():
                bits |= 1 << entry.type
            return struct.pack(">i", bits)
        if f in (fn.PARAMETER, fn.DIAGNOSIS):
            return self._numbered(f, a[0], a[1], a[2])
        if f == fn.START:
            m.start()
            return b""
        if f == fn.SELECT_FILE:
            m.select_program(self._file_name(read_path_field(cmd.data)))
            return b""
        if f == fn.SELECT_NUMBER:
            m.select_program(self._numbered_program(a[0]))
            return b""
        if f == fn.CURRENT_FOLDER:
            return path_field(FOLDER)
        if f in (fn.FOLDER_COUNT, fn.READ_FOLDER):
            if read_path_field(cmd.data).rstrip("/") + "/" != FOLDER:
                raise _Refused(EW_DATA)
            entries = self.folder()
            if f == fn.FOLDER_COUNT:
                return struct.pack(">ii", 0, len(entries))
            first, count = max(0, a[0]), max(0, a[1])
            return b"".join(e.encode() for e in entries[first : first + count])
        if f == fn.DELETE_FILE:
            self.delete(self._file_name(read_path_field(cmd.data)))
            return b""
        raise _Refused(EW_FUNC)

    # --- state ---------------------------------------------------------------------------------

    def statinfo(self) -> StatInfo:
        m = self.machine
        moving = any(axis.velocity for axis in m.axes)
        return StatInfo(MODE_AUT[m.mode], RUN[m.state], 1 if moving else 0, 0, 1 if m.emergency_stop else 0,
                        1 if m.alarms else 0, 0)  # fmt: skip

    def alarm_entries(self) -> list[AlarmEntry]:
        out = []
        for alarm in self.machine.alarms:
            kind = 4 if alarm.id == SOFT_LIMIT else (15 if alarm.severity < Severity.ERROR else 3)
            out.append(AlarmEntry(alarm.id, kind, 0, alarm.text))
        return out

    def macro(self, n: int) -> float | None:
        m = self.machine
        if n == 3901:
            return float(m.program.part_count)
        if n == 3902:
            return self.required_parts
        if 5021 <= n <= 5020 + len(m.axes):
            return round(m.axes[n - 5021].actual, 4)
        if 5041 <= n <= 5040 + len(m.axes):
            return round(m.axes[n - 5041].actual, 4)
        if n == 4120:
            return 0.0
        if n == 3011:
            return float(time.strftime("%Y%m%d"))
        if n == 3012:
            return float(time.strftime("%H%M%S"))
        return self.macros.get(n)

    def set_macro(self, n: int, value: float | None) -> None:
        if not any(lo <= n <= hi for lo, hi in MACRO_WRITABLE):
            raise _Refused(EW_NUMBER if not 1 <= n <= 99_999 else EW_PROT)
        if n == 3901:
            self.machine.program.part_count = int(value or 0)
        elif n == 3902:
            self.required_parts = float(value or 0)
        else:
            self.macros[n] = value

    def _macro_write(self, first: int, last: int, data: bytes) -> None:
        numbers = self._range(first, last)
        if len(data) != 8 * len(numbers):
            raise _Refused(EW_LENGTH)
        values = [decode_scaled(data, 8 * i) for i in range(len(numbers))]
        for n in numbers:
            if not any(lo <= n <= hi for lo, hi in MACRO_WRITABLE):
                raise _Refused(EW_PROT)
        for n, value in zip(numbers, values, strict=True):
            self.set_macro(n, value)

    def _range(self, first: int, last: int) -> list[int]:
        if not 1 <= first <= last <= 99_999 or last - first >= MAX_RANGE:
            raise _Refused(EW_NUMBER)
        return list(range(first, last + 1))

    def _positions(self, kind: int, axis: int) -> bytes:
        axes = self.machine.axes
        if kind not in fn.POSITION_TYPES.values():
            raise _Refused(EW_NUMBER)

        def value(a: int) -> float:
            ax = axes[a]
            return ax.commanded - ax.actual if kind == fn.POSITION_TYPES["distance"] else ax.actual

        if axis == -1:
            return b"".join(encode_scaled(value(i), 3) for i in range(len(axes)))
        if not 1 <= axis <= len(axes):
            raise _Refused(EW_NUMBER)
        return encode_scaled(value(axis - 1), 3)

    # --- PMC -----------------------------------------------------------------------------------

    def refresh_signals(self) -> None:
        """F signals from the machine, as the CNC sets them each scan (the face calls it before a read)."""
        m = self.machine
        f = self.pmc["F"]
        f[0] = (0x80 if m.state is MachineState.RUNNING else 0) | (
            0x10 if m.state is MachineState.PAUSED else 0
        )
        f[1] = 0x01 if m.alarms else 0
        self.pmc["G"][12] = 255 - min(255, m.override)

    def _pmc_span(self, args: tuple[int, int, int, int, int]) -> tuple[bytearray, str, int, int, int]:
        start, end, code, kind = args[0], args[1], args[2], args[3]
        area = next((name for name, c in fn.PMC_AREAS.items() if c == code), None)
        if area is None or kind not in fn.PMC_TYPE_SIZE:
            raise _Refused(EW_NUMBER if area is None else EW_DATA)
        width = fn.PMC_TYPE_SIZE[kind]
        if not 0 <= start <= end < PMC_SIZE or (end - start + 1) % width or end - start >= MAX_RANGE:
            raise _Refused(EW_NUMBER)
        return self.pmc[area], area, start, end, width

    def _pmc_read(self, args: tuple[int, int, int, int, int]) -> bytes:
        self.refresh_signals()
        memory, _, start, end, width = self._pmc_span(args)
        raw = bytes(memory[start : end + 1])
        if width == 1:
            return raw
        fmt = "<h" if width == 2 else "<i"  # PMC memory is little-endian; FOCAS carries big-endian
        out = struct.iter_unpack(fmt, raw)
        return b"".join(struct.pack(">" + fmt[1], v) for (v,) in out)

    def _pmc_write(self, args: tuple[int, int, int, int, int], data: bytes) -> None:
        memory, area, start, end, width = self._pmc_span(args)
        if area in PMC_READ_ONLY:
            raise _Refused(EW_PROT)
        if len(data) != end - start + 1:
            raise _Refused(EW_LENGTH)
        if width > 1:
            fmt = ">h" if width == 2 else ">i"
            data = b"".join(struct.pack("<" + fmt[1], v) for (v,) in struct.iter_unpack(fmt, data))
        before = bytes(memory[start : end + 1])
        memory[start : end + 1] = data
        if area == "G":
            self._ladder(before, start)

    def _ladder(self, before: bytes, start: int) -> None:
        """What the machine builder's ladder does with the G signals a client wrote."""
        g = self.pmc["G"]
        m = self.machine
        if start <= 12 < start + len(before):
            m.set_override(max(0, min(200, 255 - g[12])))
        if start <= 8 < start + len(before) and g[8] & 0x80:  # ERS: external reset
            g[8] &= 0x7F
            m.reset()
        if start <= 7 < start + len(before):
            rising = g[7] & 0x04 and not before[7 - start] & 0x04  # ST: cycle start on the rising edge
            if rising:
                m.start()

    # --- parameters and diagnostics ------------------------------------------------------------

    def _numbered(self, function: int, first: int, last: int, axis: int) -> bytes:
        if not 0 <= first <= last <= 99_999 or last - first >= 100:
            raise _Refused(EW_NUMBER)
        out = []
        for n in range(first, last + 1):
            values, is_axis = self._numbered_values(function, n)
            if axis > 0:
                if axis > MAX_AXIS:
                    raise _Refused(EW_NUMBER)
                values = [values[axis - 1]] if is_axis else values[:1]
                slots = 1
            elif axis == -1:
                slots = MAX_AXIS
            else:
                values, slots = values[:1], 1
            out.append(encode_numbered(n, axis if is_axis else 0, 3, values, slots))
        return b"".join(out)

    def _numbered_values(self, function: int, n: int) -> tuple[list[int], bool]:
        m = self.machine
        if function == fn.PARAMETER:
            if n == 1020:  # axis names as their ASCII codes
                return [ord(a.name[0]) for a in m.axes], True
            if n in (1320, 1321):
                limits = m.limits
                return [round(1000 * limits[a.name][0 if n == 1321 else 1]) for a in m.axes], True
            if n == 6711:
                return [m.program.part_count], False
            if n == 6713:
                return [int(self.required_parts)], False
            return [self.params.get(n, 0)], False
        if 300 <= n <= 399:  # position deviation, per axis (micrometres)
            return [round(1000 * (a.commanded - a.actual)) for a in m.axes], True
        return [0], False

    # --- programs ------------------------------------------------------------------------------

    def folder(self) -> list[DirEntry]:
        store = self.machine.store
        names = store.names() if hasattr(store, "names") else []
        out = []
        for name in names:
            size, stamp = _stat(store, name)
            out.append(DirEntry(name, True, size, stamp))
        return out

    def _file_name(self, path: str) -> str:
        path = path.removeprefix(FOLDER)
        if not path or "/" in path:
            raise _Refused(EW_DATA)
        return path

    def _numbered_program(self, number: int) -> str:
        for name in (f"O{number:04d}", f"O{number}"):
            if self.machine.store.exists(name):
                return name
        raise _Refused(EW_DATA)

    def delete(self, name: str) -> None:
        store = self.machine.store
        if self.machine.program.name == name and self.machine.state in (
            MachineState.RUNNING,
            MachineState.PAUSED,
        ):
            raise _Refused(EW_REJECT)
        delete = getattr(store, "delete", None)
        if delete is None or not store.exists(name):
            raise _Refused(EW_DATA)
        try:
            delete(name)
        except (ProgramNotFound, OSError):
            raise _Refused(EW_DATA) from None


def program_number(name: str) -> int:
    """The O-number of a program named O1234 (0 for other names)."""
    stem = name.split(".", 1)[0]
    if stem[:1] == "O" and stem[1:].isdigit():
        return int(stem[1:])
    return 0


def _stat(store: object, name: str) -> tuple[int, tuple[int, int, int, int, int, int]]:
    folder = getattr(store, "programs", None)
    if folder is None:
        return 0, (2000, 1, 1, 0, 0, 0)
    try:
        st = (folder / name).stat()
    except OSError:
        return 0, (2000, 1, 1, 0, 0, 0)
    t = time.localtime(st.st_mtime)
    return st.st_size, (t.tm_year, t.tm_mon, t.tm_mday, t.tm_hour, t.tm_min, t.tm_sec)

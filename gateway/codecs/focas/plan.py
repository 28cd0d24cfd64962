"""A poll group's items as few commands as possible, and each item's value out of the answers.

Items that one function answers share its command (statinfo's seven fields, every position of one
kind, the alarm list); macros close together are read as one range, PMC bytes of one area too. A
group of 50 items is then a handful of commands, sent as one multi-command request
(`max_commands` per request), so a poll cycle is one round trip for most groups.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from gateway.codecs.focas import functions as fn
from gateway.codecs.focas.address import Item
from gateway.codecs.focas.commands import PMC, Command, Reply, command
from gateway.codecs.focas.errors import EW_DATA, EW_NUMBER, FocasError, describe
from gateway.codecs.focas.values import (
    StatInfo,
    SysInfo,
    decode_alarms,
    decode_numbered,
    decode_program_name,
    decode_scaled,
    decode_scaled_list,
)

MACRO_GAP = 8  # vacant macros read rather than a second range
MACRO_SPAN = 100  # macros per range at most
PMC_GAP = 32
PMC_SPAN = 256  # bytes per range at most
MAX_ALARMS = 32
ALARM_TEXT = 64

Value = bool | int | float | str | list[int] | list[float] | list[str] | None


@dataclass(frozen=True, slots=True)
class Context:
    """What a session learnt at open: the axes' names (for `position.absolute[X]`) and sysinfo."""

    axes: tuple[str, ...] = ()
    max_axis: int = 8

    def axis_index(self, axis: str | int) -> int:
        """0-based index of an axis given by name or 1-based number; FocasError if there is none."""
        if isinstance(axis, int):
            if not 1 <= axis <= max(len(self.axes), 1) and self.axes:
                raise FocasError(f"axis {axis}: the controller has {len(self.axes)}", code=EW_NUMBER)
            return axis - 1
        if axis not in self.axes:
            raise FocasError(
                f"no axis {axis} (the controller's: {', '.join(self.axes) or 'none'})", code=EW_NUMBER
            )
        return self.axes.index(axis)


@dataclass(frozen=True, slots=True)
class Outcome:
    """One item's answer: a value, or the controller's error code for it (then `value` is None)."""

    value: Value
    error: int = 0
    reason: str = ""


Extract = Callable[[Reply, Context], Value]


@dataclass(slots=True)
class Plan:
    commands: list[Command] = field(default_factory=list)
    _uses: list[tuple[int, Extract]] = field(default_factory=list)

    def _add(self, cmd: Command) -> int:
        try:
            return self.commands.index(cmd)
        except ValueError:
            self.commands.append(cmd)
            return len(self.commands) - 1

    def batches(self, max_commands: int) -> list[list[Command]]:
        return [self.commands[i : i + max_commands] for i in range(0, len(self.commands), max_commands)]

    def outcomes(self, replies: Sequence[Reply], ctx: Context) -> list[Outcome]:
        """Per item, in the order planned. `replies` answer `commands`, in order (FocasError if not)."""
        if len(replies) != len(self.commands):
            raise FocasError(f"{len(replies)} answers to {len(self.commands)} commands")
        for reply, cmd in zip(replies, self.commands, strict=True):
            if not reply.answers(cmd):
                raise FocasError(
                    f"an answer to function {reply.function:#x} where {cmd.function:#x} was asked"
                )
        out = []
        for index, extract in self._uses:
            reply = replies[index]
            if reply.error:
                out.append(Outcome(None, reply.error, describe(reply.error)))
                continue
            try:
                out.append(Outcome(extract(reply, ctx)))
            except FocasError as exc:
                out.append(Outcome(None, exc.code if exc.code > 0 else EW_DATA, exc.reason))
            except (struct.error, IndexError, ValueError) as exc:
                out.append(Outcome(None, EW_DATA, f"unreadable answer: {exc}"))
        return out


def _macro_ranges(numbers: list[int]) -> list[tuple[int, int]]:
    ranges: list[tuple[int, int]] = []
    for n in sorted(set(numbers)):
        if ranges and n - ranges[-1][1] <= MACRO_GAP and n - ranges[-1][0] < MACRO_SPAN:
            ranges[-1] = (ranges[-1][0], n)
        else:
            ranges.append((n, n))
    return ranges


def _pmc_ranges(spans: list[tuple[int, int]], gap: int) -> list[tuple[int, int]]:
    ranges: list[tuple[int, int]] = []
    for start, end in sorted(set(spans)):
        if ranges and start - ranges[-1][1] <= gap and end - ranges[-1][0] < PMC_SPAN:
            ranges[-1] = (ranges[-1][0], max(end, ranges[-1][1]))
        else:
            ranges.append((start, end))
    return ranges


def alarm_command(max_alarms: int = MAX_ALARMS) -> Command:
    return command(fn.ALARM_MESSAGES, -1, max_alarms, 2, ALARM_TEXT)


def make_plan(items: Sequence[Item], max_alarms: int = MAX_ALARMS) -> Plan:
    """Commands for `items` and, per item in order, where its value comes from."""
    plan = Plan()
    macros = _macro_ranges([i.number for i in items if i.kind == "macro"])
    pmc: dict[tuple[str, int], list[tuple[int, int]]] = {}
    for i in items:
        if i.kind == "pmc":
            width = fn.PMC_TYPE_SIZE[i.size]
            pmc.setdefault((i.area, i.size), []).append((i.number, i.number + width - 1))
    pmc_ranges = {key: _pmc_ranges(spans, PMC_GAP) for key, spans in pmc.items()}
    for item in items:
        cmd, extract = _one(item, macros, pmc_ranges, max_alarms)
        plan._uses.append((plan._add(cmd), extract))
    return plan


def _one(
    item: Item,
    macros: list[tuple[int, int]],
    pmc_ranges: dict[tuple[str, int], list[tuple[int, int]]],
    max_alarms: int,
) -> tuple[Command, Extract]:
    k, f = item.kind, item.field
    if k == "sysinfo":
        return command(fn.SYSINFO), lambda r, c: _sysinfo_field(SysInfo.decode(r.data), f)
    if k == "status":
        return command(fn.STATINFO), lambda r, c: int(getattr(StatInfo.decode(r.data), f))
    if k == "feed":
        return command(fn.ACTUAL_FEED), lambda r, c: _number(decode_scaled(r.data))
    if k == "spindle":
        return command(fn.ACTUAL_SPINDLE), lambda r, c: _number(decode_scaled(r.data))
    if k == "position":
        axis = item.axis
        cmd = command(fn.POSITION, fn.POSITION_TYPES[f], -1)
        if axis is None:
            return cmd, lambda r, c: [_number(v) for v in decode_scaled_list(r.data, len(c.axes) or None)]
        return cmd, lambda r, c: _number(decode_scaled_list(r.data)[c.axis_index(axis)])
    if k == "program":
        if f in ("number", "main"):
            at = 0 if f == "number" else 4
            return command(fn.PROGRAM_NUMBER), lambda r, c: struct.unpack_from(">i", r.data, at)[0]
        if f == "name" or f == "select":
            return command(fn.PROGRAM_NAME), lambda r, c: decode_program_name(r.data)[1]
        if f == "sequence":
            return command(fn.SEQUENCE_NUMBER), lambda r, c: struct.unpack_from(">i", r.data)[0]
        if f == "block":
            return command(fn.EXECUTING_BLOCK, 256), lambda r, c: _block_text(r.data)
        if f == "start":  # reads as "running": statinfo's run is STRT
            return command(fn.STATINFO), lambda r, c: StatInfo.decode(r.data).run == 3
    if k == "macro":
        first, last = next((a, b) for a, b in macros if a <= item.number <= b)
        at = 8 * (item.number - first)
        return command(fn.MACRO_READ, first, last), lambda r, c: _number(decode_scaled(r.data, at))
    if k == "pmc":
        width = fn.PMC_TYPE_SIZE[item.size]
        start, end = next((a, b) for a, b in pmc_ranges[(item.area, item.size)] if a <= item.number <= b)
        cmd = command(fn.PMC_READ, start, end, fn.PMC_AREAS[item.area], item.size, device=PMC)
        at = item.number - start
        bit, inverted, size = item.bit, item.inverted, item.size
        fmt = {fn.PMC_BYTE: ">B", fn.PMC_WORD: ">h", fn.PMC_LONG: ">i"}[size]

        def pmc_value(r: Reply, c: Context) -> Value:
            value: int = struct.unpack_from(fmt, r.data, at if size == fn.PMC_BYTE else at // width * width)[
                0
            ]
            if bit is not None:
                return bool(value >> bit & 1)
            return 255 - value if inverted else value

        return cmd, pmc_value
    if k in ("param", "diag"):
        axis_arg = 0 if item.axis is None else (item.axis if isinstance(item.axis, int) else -1)
        cmd = command(fn.PARAMETER if k == "param" else fn.DIAGNOSIS, item.number, item.number, axis_arg)
        axis, number = item.axis, item.number

        def numbered(r: Reply, c: Context) -> Value:
            slots = _slots(r.data)
            for n, _axis, _kind, values in decode_numbered(r.data, slots):
                if n == number:
                    if isinstance(axis, str):
                        return values[c.axis_index(axis)]
                    return values[0]
            raise FocasError(f"{k} {number} is not in the answer", code=EW_NUMBER)

        return cmd, numbered
    if k == "alarms":
        cmd = alarm_command(max_alarms)
        if f == "count":
            return cmd, lambda r, c: len(decode_alarms(r.data))
        if f == "message":
            return cmd, lambda r, c: [a.message for a in decode_alarms(r.data)]
        return cmd, lambda r, c: [int(getattr(a, f)) for a in decode_alarms(r.data)]
    if k == "alarm_status":
        return command(fn.ALARM_STATUS), lambda r, c: struct.unpack_from(">i", r.data)[0]
    raise ValueError(f"no plan for {item}")  # parse_address makes this unreachable


def _slots(data: bytes) -> int:
    """How many 32-bit values each parameter entry holds (1 for a plain one, max_axis for an axis one)."""
    if len(data) < 8:
        raise FocasError(f"a parameter answer of {len(data)} bytes")
    return max(1, (len(data) - 8) // 4)


def _number(value: float | None) -> float:
    if value is None:
        raise FocasError("the controller has no value there (vacant)", code=EW_DATA)
    return value


def _sysinfo_field(info: SysInfo, name: str) -> Value:
    value = getattr(info, name)
    return value if isinstance(value, (int, str)) else str(value)


def _block_text(data: bytes) -> str:
    if len(data) < 4:
        raise FocasError("an executing-block answer without its block number")
    return data[4:].split(b"\x00", 1)[0].decode("ascii", errors="replace").strip()

"""Alarms as a controller reports them: a number, a text and a severity class."""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum


class Severity(IntEnum):
    INFO = 1
    WARNING = 2
    ERROR = 3
    FATAL = 4


@dataclass(frozen=True, slots=True)
class Alarm:
    id: int
    text: str
    severity: Severity = Severity.ERROR

    @property
    def stops_machine(self) -> bool:
        """Errors and fatal alarms abort the program and put the machine in Alarm."""
        return self.severity >= Severity.ERROR


# Fanuc's numbers for the reader/punch interface (serial DNC), so the gateway sees what a shop knows.
NO_PROGRAM_SPACE = 70
DNC_COMMUNICATION = 85
DNC_LINE_DROPPED = 86
DNC_BUFFER_OVERFLOW = 87
SOFT_LIMIT = 1001
PROGRAM_ERROR = 2001
PROGRAM_NOT_FOUND = 2002


def soft_limit(axis: str, direction: str, line: int) -> Alarm:
    return Alarm(SOFT_LIMIT, f"Soft limit {axis}{direction} exceeded at line {line}")


def program_error(line: int, reason: str) -> Alarm:
    return Alarm(PROGRAM_ERROR, f"Program error at line {line}: {reason}")


def program_not_found(name: str) -> Alarm:
    return Alarm(PROGRAM_NOT_FOUND, f"Program not found: {name}")


def no_program_space(size: int) -> Alarm:
    return Alarm(NO_PROGRAM_SPACE, f"No program space in memory: program over {size} bytes")


def dnc_communication(errors: int, what: str) -> Alarm:
    return Alarm(DNC_COMMUNICATION, f"Communication error: {errors} {what} on the DNC line")


def dnc_line_dropped(during: str) -> Alarm:
    return Alarm(DNC_LINE_DROPPED, f"DR signal off: the DNC line dropped during {during}")


def dnc_buffer_overflow(size: int, after_dc3: int) -> Alarm:
    return Alarm(
        DNC_BUFFER_OVERFLOW,
        f"Buffer overflow: over {size} bytes in the DNC receive buffer, {after_dc3} characters after DC3",
    )

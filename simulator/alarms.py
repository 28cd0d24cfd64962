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


SOFT_LIMIT = 1001
PROGRAM_ERROR = 2001
PROGRAM_NOT_FOUND = 2002


def soft_limit(axis: str, direction: str, line: int) -> Alarm:
    return Alarm(SOFT_LIMIT, f"Soft limit {axis}{direction} exceeded at line {line}")


def program_error(line: int, reason: str) -> Alarm:
    return Alarm(PROGRAM_ERROR, f"Program error at line {line}: {reason}")


def program_not_found(name: str) -> Alarm:
    return Alarm(PROGRAM_NOT_FOUND, f"Program not found: {name}")

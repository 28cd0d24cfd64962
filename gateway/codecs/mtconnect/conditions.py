"""Active conditions as text: how a CONDITION data item's state lives in a `String[]` variable of the tree.

A condition data item can hold several active conditions at once (a Fault per native
code), which no OPC UA built-in type carries. The gateway keeps them as a list of
strings, one per active Warning or Fault, each in SHDR's own condition field order:

    FAULT|E42:c1|2|HIGH|Laser overheated     level|native code[:condition id]|native severity|qualifier|text

An empty list is Normal; UNAVAILABLE is a Bad quality, not a value. The MTConnect
source writes these lists, the alarm source (gateway/alarms/sources.py) and the agent
face read them: one format, three places, so it lives here.
"""

from __future__ import annotations

from dataclasses import dataclass

from gateway.codecs.mtconnect.shdr import quote_field, split_fields

ACTIVE_LEVELS = ("WARNING", "FAULT")


@dataclass(frozen=True, slots=True)
class ActiveCondition:
    level: str  # WARNING or FAULT
    native_code: str | None = None
    native_severity: str | None = None
    qualifier: str | None = None
    text: str = ""
    condition_id: str | None = None

    @property
    def key(self) -> str:
        """What tells two active conditions of one data item apart: the id, else the code, else the level."""
        return self.condition_id or self.native_code or self.level


def format_condition_text(condition: ActiveCondition) -> str:
    if condition.level not in ACTIVE_LEVELS:
        raise ValueError(f"an active condition is WARNING or FAULT, not {condition.level!r}")
    code = condition.native_code or ""
    if ":" in code:
        raise ValueError(f"a native code cannot contain ':' (it separates the condition id): {code!r}")
    if condition.condition_id is not None and condition.condition_id != condition.native_code:
        code = f"{code}:{condition.condition_id}"
    fields = [
        condition.level,
        code,
        condition.native_severity or "",
        condition.qualifier or "",
        condition.text.replace("\r", " ").replace("\n", " "),
    ]
    return "|".join(quote_field(f) for f in fields)


def parse_condition_text(text: str) -> ActiveCondition:
    """The condition one list entry names. Raises ValueError for an entry that is not one."""
    fields = split_fields(text)
    fields += [""] * (5 - len(fields))
    level, code, severity, qualifier = (f.strip() for f in fields[:4])
    message = "|".join(fields[4:]) if len(fields) > 5 else fields[4]
    level = level.upper()
    if level not in ACTIVE_LEVELS:
        raise ValueError(f"{text[:60]!r} does not start with WARNING or FAULT")
    native: str | None = code or None
    condition_id: str | None = native
    if ":" in code:
        before, _, after = code.partition(":")
        native, condition_id = before or None, after or before or None
    if qualifier and qualifier not in ("HIGH", "LOW"):
        qualifier = ""
    return ActiveCondition(level, native, severity or None, qualifier or None, message, condition_id)

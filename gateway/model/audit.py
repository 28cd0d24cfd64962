"""One audit entry, and how values appear in it.

Pure data, owned by the model: the tree builds an entry for every write and call
(gateway/model/tree.py) and hands it to `VariableTree.audit_sinks`; the audit
trail (gateway/audit/trail.py, store.py), which sits above the model, logs and
stores them, and the CLI prints them. Values are kept as short JSON text, so a
5 MB program passed to `Programs.Put` cannot bloat the table.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

MAX_TEXT = 200  # characters of one value kept in the trail


@dataclass(frozen=True, slots=True)
class AuditEntry:
    time: datetime  # when the request arrived (UTC)
    kind: str  # "write" | "call" (others may add their own, e.g. "acknowledge")
    machine: str
    target: str  # variable path, or Object.Method
    origin: str  # the sink: opcua, mqtt, copydata, jobs, demo…
    user: str | None
    role: str | None
    old: str | None  # JSON text (writes: the value shown before the write); None when not applicable
    new: str | None  # JSON text: the value written, or the list of arguments
    status: str  # "Good", or the Bad status name
    reason: str  # empty when Good
    duration: float  # seconds

    @property
    def ok(self) -> bool:
        return self.status == "Good"

    def describe(self) -> str:
        """One log line."""
        who = self.user or "anonymous"
        role = f", {self.role}" if self.role else ""
        if self.kind == "write":
            what = f"write {self.machine}/{self.target} {self.old} -> {self.new}"
        else:
            what = f"{self.kind} {self.machine}/{self.target}({(self.new or '[]')[1:-1]})"
        result = "ok" if self.ok else f"{self.status}: {self.reason}"
        return f"{what} by {who} via {self.origin}{role}: {result} ({self.duration * 1000:.0f} ms)"


def as_text(value: Any) -> str:
    """A value as short JSON text (longer texts are cut, with their full length noted)."""
    text = json.dumps(_plain(value), ensure_ascii=False, separators=(",", ":"))
    if len(text) > MAX_TEXT:
        text = f"{text[:MAX_TEXT]}… ({len(text)} chars)"
    return text


def _plain(value: Any) -> Any:
    if value is None or isinstance(value, (bool, int, str)):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else str(value)
    if isinstance(value, datetime):
        ts = value if value.tzinfo else value.replace(tzinfo=UTC)
        return ts.astimezone(UTC).isoformat().replace("+00:00", "Z")
    if isinstance(value, (bytes, bytearray)):
        return f"<{len(value)} bytes>"
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value[:50]] + ([f"… {len(value)} items"] if len(value) > 50 else [])
    return str(value)

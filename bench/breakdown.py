"""Where the gateway's CPU goes, by part: py-spy's collapsed stacks sorted into the parts issue 13 names.

Each sample is given to one part, by its innermost frame that belongs to one
(so `json_text` called from the MQTT sink counts as JSON, the sink's own code as
the sink). Frames of the standard library's asyncio, of native code (py-spy
`--native`) and of anything unknown are passed over on the way out, so that an
`Event.set()` in the hub counts for the hub; a stack with no known frame at all
is the event loop's own work when it passes through asyncio (selecting, running
callbacks) and "other" otherwise. Threads parked in a wait (a lock, a queue,
the selector), which py-spy `--native` cannot tell from working ones, are left
out. asyncua's shared encoding code (`asyncua/ua`, `asyncua/common`) counts for
the client or the server by who called it.
"""

from __future__ import annotations

import collections
from collections.abc import Iterable

PARTS = (
    "OPC UA client decoding (asyncua client, source driver)",
    "tree and hub",
    "OPC UA server update (sink, asyncua server)",
    "JSON payloads",
    "MQTT sink (routes, emit, backlog)",
    "paho",
    "event loop",
    "garbage collector",
    "other (other sinks, jobs, alarms, …)",
)
CLIENT, TREE, SERVER, JSON, SINK, PAHO, LOOP, GC, OTHER = PARTS

# (substring of a frame's file, part); the first that matches a frame decides for that frame
_RULES: tuple[tuple[str, str], ...] = (
    ("gateway/sinks/mqtt/payloads.py", JSON),
    ("json/", JSON),
    ("paho/", PAHO),
    ("gateway/sinks/mqtt/", SINK),
    ("gateway/sinks/mqtt_link/", SINK),  # its paho adapter and backlog, below the MQTT sink since issue 24
    ("gateway/codecs/mqtt_publish.py", SINK),
    ("gateway/model/", TREE),
    ("gateway/sinks/opcua/", SERVER),
    ("asyncua/server/", SERVER),
    ("gateway/shims/asyncua_server.py", SERVER),
    ("gateway/sources/", CLIENT),
    ("asyncua/client/", CLIENT),
    ("gateway/", OTHER),  # the other sinks (web console, COPYDATA, …), jobs, alarms: not the event loop's
)
_SHARED = ("asyncua/",)  # decided by a caller further out
_LOOP = ("asyncio/", "selectors.py", "uvloop")


def part_of(frames: list[str]) -> str:
    """The part one stack (outermost first) is charged to."""
    shared = False
    through_loop = False
    for frame in reversed(frames):
        if frame.startswith("<gc>") or "gc_collect" in frame or frame.startswith("collect ("):
            return GC
        for needle, part in _RULES:
            if needle in frame:
                return part
        if any(s in frame for s in _SHARED):
            shared = True
        if any(s in frame for s in _LOOP):
            through_loop = True
    if shared:
        return CLIENT  # asyncua code that no server frame called: the client's connection and decoding
    return LOOP if through_loop else OTHER


_WAITS = ("Condition.wait (", "Queue.get (", "select (selectors.py", "Event.wait (threading.py")


def waiting(frames: list[str]) -> bool:
    """A thread parked in a wait (with --native py-spy cannot tell it from a working one): its innermost
    Python frame is a wait, or it has none, or it blocks on a lock."""
    if any("PyThread_acquire_lock_timed" in frame for frame in frames):
        return True
    for frame in reversed(frames):
        if ".py:" in frame or ".py)" in frame:
            return frame.startswith(_WAITS)
    return True


def breakdown(stacks: Iterable[tuple[list[str], int]]) -> dict[str, float]:
    """Percent of the samples per part (the parts in PARTS order, all of them)."""
    counts: collections.Counter[str] = collections.Counter()
    total = 0
    for frames, n in stacks:
        if waiting(frames):
            continue
        counts[part_of(frames)] += n
        total += n
    return {part: round(100.0 * counts[part] / total, 1) if total else 0.0 for part in PARTS}


def parse_collapsed(text: str) -> list[tuple[list[str], int]]:
    """py-spy's `--format raw` (collapsed stacks: `frame;frame;frame count`) as (frames, count)."""
    out = []
    for line in text.splitlines():
        stack, _, count_text = line.rpartition(" ")
        if not stack or not count_text.isdigit():
            continue
        out.append(([f for f in stack.split(";") if f], int(count_text)))
    return out


def render(parts: dict[str, float], samples: int | None = None) -> list[str]:
    """One line per part, in a Markdown table."""
    lines = ["| part | % of CPU samples |", "|---|---:|"]
    lines += [f"| {part} | {share:.1f} |" for part, share in parts.items()]
    if samples is not None:
        lines.append(f"| (samples) | {samples} |")
    return lines

"""`cnc-gateway discover focas://host:8193 --machine fanuc-1`: a starting mapping file from a Fanuc.

It opens a session, reads sysinfo and the axes' names, tries one batched request of every item it
would map, and writes those the control answers: what it is, statinfo, each axis' positions, feed
and spindle, the program, parts, and the alarm list with the `alarms:` section that follows it.
Items the control refuses (EW_FUNC, EW_NOOPT: a series without them) are left out, with a comment.
"""

from __future__ import annotations

import math
from datetime import UTC, datetime
from typing import Any
from urllib.parse import urlsplit

import yaml

from gateway.codecs.focas.address import parse_address
from gateway.codecs.focas.errors import describe
from gateway.codecs.focas.plan import make_plan
from gateway.errors import SourceError
from gateway.settings.names import MACHINE_RE
from gateway.sources.focas.config import DEFAULT_FOCAS_PORT
from gateway.sources.focas.session import FocasSession

SLOW = 60_000  # ms: what does not change


def parse_url(url: str) -> tuple[str, int]:
    parts = urlsplit(url)
    if parts.scheme != "focas" or not parts.hostname:
        raise ValueError(f"{url!r} is not focas://host[:port]")
    try:
        port = parts.port or DEFAULT_FOCAS_PORT
    except ValueError:
        raise ValueError(f"{url!r} has an invalid port") from None
    return parts.hostname, port


def candidates(axes: tuple[str, ...]) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = [
        {
            "path": "Controller/Type",
            "source": "sysinfo.cnc_type",
            "type": "String",
            "sampling_interval": SLOW,
        },
        {
            "path": "Controller/Series",
            "source": "sysinfo.series",
            "type": "String",
            "sampling_interval": SLOW,
        },
        {
            "path": "Controller/Version",
            "source": "sysinfo.version",
            "type": "String",
            "sampling_interval": SLOW,
        },
    ]
    out += [{"path": f"Machine/{f.capitalize()}", "source": f"status.{f}", "type": "Int16"}
            for f in ("mode", "run", "motion", "alarm", "emergency")]  # fmt: skip
    for axis in axes:
        for kind, name in (("absolute", "Position"), ("machine", "Machine"), ("distance", "DistanceToGo")):
            out.append(
                {"path": f"Axes/{axis}/{name}", "source": f"position.{kind}[{axis}]", "type": "Double"}
            )
    out += [
        {"path": "Feed/Rate", "source": "feed.actual", "type": "Double"},
        {"path": "Feed/Override", "source": "feed.override", "type": "Int32", "unit": "%"},
        {"path": "Spindle/Speed", "source": "spindle.actual", "type": "Double"},
        {"path": "Spindle/Override", "source": "spindle.override", "type": "Int32", "unit": "%"},
        {"path": "Program/Number", "source": "program.number", "type": "Int32"},
        {"path": "Program/Name", "source": "program.name", "type": "String"},
        {"path": "Program/Sequence", "source": "program.sequence", "type": "Int32"},
        {"path": "Program/Block", "source": "program.block", "type": "String"},
        {"path": "Parts/Count", "source": "parts.count", "type": "Int32", "sampling_interval": 1000},
        {"path": "Parts/Required", "source": "parts.required", "type": "Int32", "sampling_interval": 1000},
        {
            "path": "ActiveAlarms/Numbers",
            "source": "alarms.number",
            "type": "Int32[]",
            "sampling_interval": 250,
        },
        {"path": "ActiveAlarms/Types", "source": "alarms.type", "type": "Int32[]", "sampling_interval": 250},
        {
            "path": "ActiveAlarms/Messages",
            "source": "alarms.message",
            "type": "String[]",
            "sampling_interval": 250,
        },
    ]
    return out


async def discover_focas(url: str, *, machine: str, timeout: float = 5.0) -> str:
    if not MACHINE_RE.match(machine):
        raise ValueError(f"machine name {machine!r} must be lower-case letters, digits, '-' or '_'")
    host, port = parse_url(url)
    session = FocasSession(host, port, timeout)
    await session.open()
    try:
        await session.learn()
        wanted = candidates(session.context.axes)
        plan = make_plan([parse_address(v["source"]) for v in wanted])
        replies = [r for batch in plan.batches(32) for r in await session.request(batch)]
        outcomes = plan.outcomes(replies, session.context)
    finally:
        await session.close()
    info = session.sysinfo
    assert info is not None
    kept, dropped = [], []
    for var, outcome in zip(wanted, outcomes, strict=True):
        if outcome.error in (1, 6):  # EW_FUNC, EW_NOOPT: not on this control
            dropped.append(f"{var['source']} ({describe(outcome.error)})")
        else:
            kept.append(var)
    return render(
        host, port, machine, kept, dropped, f"{info.cnc_type}{info.mt_type} {info.series} {info.version}"
    )


def _flow(value: Any) -> str:
    return str(yaml.safe_dump([value], default_flow_style=True, width=math.inf)).strip()[1:-1]


def render(
    host: str, port: int, machine: str, variables: list[dict[str, Any]], dropped: list[str], what: str
) -> str:
    stamp = datetime.now(UTC).isoformat(timespec="seconds")
    lines = [
        "# yaml-language-server: $schema=./mapping.schema.json",
        f"# Written by `cnc-gateway discover focas://{host}:{port}` on {stamp}: a Fanuc {what}.",
        "# Add macros (#500), PMC data (pmc:R100.3), parameters (param:6711) as needed (docs/focas.md).",
    ]
    lines += [f"# left out, the control refused: {d}" for d in dropped]
    lines += [
        f"machine: {machine}",
        f"description: {_flow(f'Fanuc {what} at {host}')}",
        "",
        "driver:",
        "  type: focas",
        f"  host: {_flow(host)}",
        f"  port: {port}",
        "  sessions: 2",
        "",
        "defaults:",
        "  sampling_interval: 100",
        "",
        "variables:",
    ]
    lines += [f"  - {_flow(v)}" for v in variables]
    paths = {v["path"] for v in variables}
    if "ActiveAlarms/Numbers" in paths and "ActiveAlarms/Messages" in paths:
        lines += [
            "",
            "alarms:",
            "  source: {type: arrays, ids: ActiveAlarms/Numbers, texts: ActiveAlarms/Messages"
            + (", severities: ActiveAlarms/Types}" if "ActiveAlarms/Types" in paths else "}"),
            "  severity: {3: 700, 4: 700, 15: 400}   # alarm type: 3 PS, 4 OT, 15 EX (docs/focas.md)",
            "  default_severity: 600",
        ]
    return "\n".join(lines) + "\n"


__all__ = ["SourceError", "discover_focas", "parse_url", "render"]

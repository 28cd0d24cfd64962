"""Fault drills: small counts in `make test`, large ones in `make soak`.

`CNC_DRILL_SCALE=soak` picks the soak counts; `CNC_DRILL_<NAME>=N` (for example
`CNC_DRILL_GATEWAY_KILLS=200`) sets one drill's count directly. Every drill
reports its counts through `drill_report`: as junit properties, as a line on the
terminal while the run goes on (past pytest's output capture, so `make soak`
shows progress), and again in a "reliability drills" section at the end.
"""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from tests.integration.jobs.conftest import harness, renames, store  # noqa: F401 - fixtures for the drills

SCALE = os.environ.get("CNC_DRILL_SCALE", "small").strip().lower() or "small"
if SCALE not in ("small", "soak"):
    raise pytest.UsageError(f"CNC_DRILL_SCALE must be 'small' or 'soak', not {SCALE!r}")

# drill -> (small, soak)
COUNTS: dict[str, tuple[int, int]] = {
    "broker_restarts": (3, 30),
    "controller_restarts": (3, 30),
    "mtconnect_restarts": (3, 30),  # per mode: an SHDR adapter, an upstream agent
    "gateway_kills": (5, 50),
    "dnc_cuts": (3, 30),  # device-server connections cut mid-drip
    "slow_consumers": (10_000, 150_000),  # changes that stream past the stalled consumers
    "security_rounds": (1, 20),  # rounds of tests/corpus/mqtt/response_topics.yaml in the security drill
    "ftp_races": (6, 200),  # uploads whose passive port another host connects to first (test_security_ftp)
    "held_addresses": (2, 20),  # addresses that hold inbox sessions open without logging in
    "guessing_addresses": (2, 30),  # addresses that guess passwords on the web console and the FTP inbox
    "slow_connections": (1000, 1000),  # per HTTP face, held open against the web console and MTConnect
    "paused_holders": (3, 30),  # lease holders stopped (SIGSTOP) past their lease, then continued
    "database_outages": (3, 30),  # the job queue's PostgreSQL cut off and back under a running job service
    "shard_kills": (3, 30),  # a shard of `cnc-gateway fleet` SIGKILLed while another's inbox takes its jobs
    "lease_takeovers": (3, 30),  # a lease-served shard SIGKILLed: another takes its machines over
}


def count(drill: str) -> int:
    """How many times (or how much) `drill` runs at this scale."""
    override = os.environ.get(f"CNC_DRILL_{drill.upper()}")
    if override:
        return int(override)
    small, soak = COUNTS[drill]
    return soak if SCALE == "soak" else small


class Records(logging.Handler):
    """Every log record of a run, from every logger (the gateway's, and the libraries' under it)."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


@pytest.fixture
def records() -> Iterator[Records]:
    """The run's log records, INFO and up (the root logger set to INFO meanwhile)."""
    handler = Records()
    root = logging.getLogger()
    old = root.level
    root.setLevel(logging.INFO)
    root.addHandler(handler)
    yield handler
    root.removeHandler(handler)
    root.setLevel(old)


_LINES: list[str] = []

Report = Callable[..., str]


@pytest.fixture
def drill_report(request: pytest.FixtureRequest, record_property: Callable[[str, Any], None]) -> Report:
    """`drill_report("broker restarts", published=…, missing=0)`: record and show a drill's counts."""

    def report(drill: str, **counts: Any) -> str:
        line = f"{drill} [{SCALE}]: " + ", ".join(f"{key}={value}" for key, value in counts.items())
        for key, value in counts.items():
            record_property(key, value)
        _LINES.append(line)
        config = request.config
        capture = config.pluginmanager.getplugin("capturemanager")
        terminal = config.pluginmanager.getplugin("terminalreporter")
        if capture is not None and terminal is not None:
            with capture.global_and_fixture_disabled():
                terminal.write_line(f"[drill] {line}")
        else:  # pragma: no cover - pytest without its terminal (xdist workers)
            sys.stderr.write(f"[drill] {line}\n")
        return line

    return report


def pytest_terminal_summary(terminalreporter: Any) -> None:
    if _LINES:
        terminalreporter.section("reliability drills")
        for line in _LINES:
            terminalreporter.write_line(line)

import os
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

# Property tests check what comes out, never how fast: on a shared 2-core machine (CI, or helpers running
# suites side by side) a slow draw is load, not a bug, so no per-example deadline and no too-slow check.
settings.register_profile(
    "shared-machine", deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large]
)
settings.load_profile("shared-machine")

# A simulator started by a test (in-process or `cnc-simulator`) takes no fixed DNC port unless asked to.
os.environ.setdefault("CNC_SIM_DNC_PORT", "off")
os.environ.setdefault("CNC_SIM_DNC_RFC2217_PORT", "off")
os.environ.setdefault("CNC_SIM_SHDR_PORT", "off")  # and no fixed SHDR (MTConnect adapter) port either
os.environ.setdefault("CNC_SIM_FOCAS_PORT", "off")  # nor FOCAS (8193)
os.environ.setdefault("CNC_SIM_HAAS_PORT", "off")  # nor Haas MDC (5051)
os.environ.setdefault("CNC_SIM_MODBUS_PORT", "off")  # nor the chiller's Modbus TCP port
os.environ.setdefault("CNC_SIM_S7_PORT", "off")  # nor the PLC's S7 port

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # so tests can `from tests.waiting import ...`


@pytest.fixture(autouse=True)
def _gc_state() -> Iterator[None]:
    """Every test leaves the garbage collector as it found it (tests/gc_state.py)."""
    from tests.gc_state import gc_state_kept

    with gc_state_kept():
        yield


@pytest.fixture(autouse=True)
def _hang_report(request: pytest.FixtureRequest) -> Iterator[None]:
    """A test still running shortly before its timeout prints its loop's tasks (tests/hang_report.py)."""
    from tests.hang_report import watch

    marker = request.node.get_closest_marker("timeout")
    timeout = (
        float(marker.args[0]) if marker and marker.args else float(request.config.getini("timeout") or 0)
    )
    with watch(timeout):
        yield


@pytest.fixture
def root() -> Path:
    return ROOT


@pytest.fixture
def unused_port() -> int:
    from tests.waiting import free_port

    return free_port()


@pytest.fixture
def postgres_url() -> Iterator[str]:
    """A fresh PostgreSQL database for this test (tests/postgres.py), dropped afterwards."""
    from tests.postgres import database

    with database() as url:
        yield url

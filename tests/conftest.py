import os
import sys
from pathlib import Path

import pytest

# A simulator started by a test (in-process or `cnc-simulator`) takes no fixed DNC port unless asked to.
os.environ.setdefault("CNC_SIM_DNC_PORT", "off")
os.environ.setdefault("CNC_SIM_DNC_RFC2217_PORT", "off")

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # so tests can `from tests.waiting import ...`


@pytest.fixture
def root() -> Path:
    return ROOT


@pytest.fixture
def unused_port() -> int:
    from tests.waiting import free_port

    return free_port()

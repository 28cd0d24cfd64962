import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # so tests can `from tests.waiting import ...`


@pytest.fixture
def root() -> Path:
    return ROOT


@pytest.fixture
def unused_port() -> int:
    from tests.waiting import free_port

    return free_port()

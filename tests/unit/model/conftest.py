import pytest

from tests.loops import LoopFactory, both


def pytest_asyncio_loop_factories(config: pytest.Config, item: pytest.Item) -> dict[str, LoopFactory]:
    """The hub's tests on asyncio's loop and on uvloop (tests/loops.py)."""
    return both(item, {"test_hub.py"})

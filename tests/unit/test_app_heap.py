"""settled_heap: start-up runs without collector passes, then what it built is frozen, and garbage is not."""

from __future__ import annotations

import gc
import weakref
from collections.abc import Iterator

import pytest

from gateway.app import YOUNG_THRESHOLD, settled_heap


class Node:
    def __init__(self) -> None:
        self.me = self  # a reference cycle: only the cyclic collector frees it


@pytest.fixture(autouse=True)
def restore_gc() -> Iterator[None]:
    enabled, threshold = gc.isenabled(), gc.get_threshold()
    yield
    gc.unfreeze()
    gc.set_threshold(*threshold)
    if enabled:
        gc.enable()


def test_start_up_objects_are_frozen_and_the_collector_is_on_again() -> None:
    gc.enable()
    gc.unfreeze()
    gc.set_threshold(700, 10, 10)
    with settled_heap():
        assert not gc.isenabled()  # no passes while start-up builds its objects
        kept = [Node() for _ in range(100)]
    assert gc.isenabled()
    assert gc.get_freeze_count() >= len(kept)
    assert gc.get_threshold()[0] == YOUNG_THRESHOLD  # fewer young passes, so fewer promotions and full passes


def test_start_up_garbage_is_collected_not_frozen() -> None:
    gc.enable()
    gc.unfreeze()
    with settled_heap():
        garbage = weakref.ref(Node())  # unreachable at once, but for its own cycle
        assert garbage() is not None  # the collector is off: nothing freed it yet
    assert garbage() is None


def test_a_failed_start_up_freezes_nothing_and_restores_the_collector() -> None:
    gc.enable()
    gc.unfreeze()
    with pytest.raises(RuntimeError), settled_heap():
        raise RuntimeError("a sink could not start")
    assert gc.isenabled()
    assert gc.get_freeze_count() == 0


def test_a_disabled_collector_stays_disabled() -> None:
    gc.disable()
    gc.unfreeze()
    with settled_heap():
        pass
    assert not gc.isenabled()

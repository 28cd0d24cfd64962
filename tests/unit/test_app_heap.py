"""settled_heap: start-up runs without collector passes, then what it built is frozen, and garbage is not."""

from __future__ import annotations

import gc
import weakref

import pytest

from gateway.shims.heap import YOUNG_THRESHOLD, HeapHold, settled_heap
from tests.gc_state import gc_state_kept


class Node:
    def __init__(self) -> None:
        self.me = self  # a reference cycle: only the cyclic collector frees it


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


def test_what_settled_heap_leaves_is_undone_after_the_test() -> None:
    """tests/conftest.py wraps each test in gc_state_kept: the raised threshold and the frozen heap go."""
    gc.enable()
    gc.unfreeze()
    gc.set_threshold(700, 10, 10)
    with gc_state_kept():
        with settled_heap():
            kept = [Node() for _ in range(10)]
        assert gc.get_threshold()[0] == YOUNG_THRESHOLD
        assert gc.get_freeze_count() >= len(kept)
    assert gc.get_threshold() == (700, 10, 10)
    assert gc.get_freeze_count() == 0
    assert gc.isenabled()


def test_a_hold_settled_later_turns_the_collector_on_when_asked() -> None:
    gc.disable()  # as `cnc-gateway run` pauses it while loading the configuration
    gc.unfreeze()
    hold = HeapHold(enable=True)
    kept = [Node() for _ in range(10)]
    assert not gc.isenabled()
    hold.settle()
    assert gc.isenabled()
    assert gc.get_freeze_count() >= len(kept)
    frozen = gc.get_freeze_count()
    hold.settle()  # once only
    hold.release()  # after settling: nothing to undo
    assert gc.get_freeze_count() == frozen
    assert gc.isenabled()


def test_a_hold_released_unsettled_freezes_nothing() -> None:
    gc.enable()
    gc.unfreeze()
    hold = HeapHold()
    assert not gc.isenabled()
    hold.release()
    assert gc.isenabled()
    assert gc.get_freeze_count() == 0

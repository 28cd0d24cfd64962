"""The observation buffer: sequence numbers, wrap-around, /current (also at=), /sample and OUT_OF_RANGE."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.codecs.mtconnect.buffer import Checkpoint, Entry, ObservationBuffer
from gateway.codecs.mtconnect.errors import ErrorCode, OutOfRange, ValueRejected

from .machines import laser, shop

T = "2024-05-01T12:00:00.000000Z"
CATALOG = shop(1)
X, Y, EXEC, SYSTEM, PROGRAM = "m1_Xpos", "m1_Ypos", "m1_exec", "m1_system", "m1_program"


def buffer(size: int = 8, checkpoint_every: int | None = None) -> ObservationBuffer:
    return ObservationBuffer(CATALOG, instance_id=42, size=size, checkpoint_every=checkpoint_every)


def fill(buf: ObservationBuffer, n: int, item: str = X) -> list[Entry]:
    out = []
    for i in range(n):
        entry = buf.add_value(item, T, float(buf.next_sequence * 1000 + i))
        assert entry is not None
        out.append(entry)
    return out


def test_sequences_start_at_one_and_the_window_follows() -> None:
    buf = buffer()
    assert (buf.first_sequence, buf.last_sequence, buf.next_sequence, len(buf)) == (1, 0, 1, 0)
    entries = fill(buf, 3)
    assert [e.sequence for e in entries] == [1, 2, 3]
    assert (buf.first_sequence, buf.last_sequence, buf.next_sequence, len(buf)) == (1, 3, 4, 3)


def test_the_ring_wraps_and_forgets_the_oldest() -> None:
    buf = buffer(size=8)
    entries = fill(buf, 20)
    assert (buf.first_sequence, buf.last_sequence, buf.next_sequence, len(buf)) == (13, 20, 21, 8)
    assert buf.get(12) is None and buf.get(21) is None
    assert buf.get(13) is entries[12] and buf.get(20) is entries[19]
    assert [e.sequence for e in buf.entries_between(0, 100)] == list(range(13, 21))


def test_a_repeated_value_is_not_stored_unless_the_item_is_discrete_or_asked() -> None:
    buf = buffer()
    assert buf.add_value(EXEC, T, "ACTIVE") is not None
    assert buf.add_value(EXEC, T, "active") is None  # the same word once normalised
    assert buf.add_value(EXEC, T, "ACTIVE", dedupe=False) is not None
    assert buf.add_value("m1_asset_chg", T, "T1", asset_type="CuttingTool") is not None
    assert buf.add_value("m1_asset_chg", T, "T1", asset_type="CuttingTool") is not None  # discrete
    assert buf.next_sequence == 5


@pytest.mark.parametrize(
    ("item", "value", "message"),
    [
        (X, "fast", "needs a number"),
        (X, True, "needs a number"),
        ("m1_pathpos", [1, 2], "needs 3 numbers"),
        (EXEC, "RUNNING", "must be one of"),
        ("m1_line", 1.5, "needs an integer"),
        ("m1_asset_chg", "T1", "needs the asset's type"),
        (SYSTEM, "FAULT", "use add_condition"),
    ],
)
def test_values_an_element_cannot_hold_are_rejected(item: str, value: object, message: str) -> None:
    buf = buffer()
    with pytest.raises(ValueRejected, match=message):
        buf.add_value(item, T, value)  # type: ignore[arg-type]
    assert buf.next_sequence == 1


def test_conditions_keep_every_active_fault_until_cleared() -> None:
    buf = buffer(size=64)
    buf.add_condition(SYSTEM, T, "NORMAL")
    buf.add_condition(SYSTEM, T, "FAULT", native_code="E1", text="laser hot")
    buf.add_condition(SYSTEM, T, "WARNING", native_code="W7")
    levels = [(e.level, e.condition_id) for e in buf.current()[0] if e.item_id == SYSTEM]
    assert levels == [("Fault", "E1"), ("Warning", "W7")]
    assert buf.add_condition(SYSTEM, T, "FAULT", native_code="E1", text="laser hot") is None  # no change
    buf.add_condition(SYSTEM, T, "FAULT", native_code="W7")  # the warning became a fault
    buf.add_condition(SYSTEM, T, "NORMAL", condition_id="E1")
    levels = [(e.level, e.condition_id) for e in buf.current()[0] if e.item_id == SYSTEM]
    assert levels == [("Fault", "W7")]
    buf.add_condition(SYSTEM, T, "NORMAL", condition_id="W7")
    levels = [(e.level, e.condition_id) for e in buf.current()[0] if e.item_id == SYSTEM]
    assert levels == [("Normal", "W7")]
    buf.add_condition(SYSTEM, T, "FAULT")  # no code: the data item id is the condition id
    assert [e.condition_id for e in buf.current()[0] if e.item_id == SYSTEM] == [SYSTEM]
    buf.add_condition(SYSTEM, T, "UNAVAILABLE", native_code="ignored")
    current = [e for e in buf.current()[0] if e.item_id == SYSTEM]
    assert [(e.level, e.native_code, e.unavailable) for e in current] == [("Unavailable", None, True)]


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [({"level": "HOT"}, "condition level"), ({"level": "FAULT", "qualifier": "MEDIUM"}, "qualifier")],
)
def test_bad_conditions_are_rejected(kwargs: dict[str, str], message: str) -> None:
    with pytest.raises(ValueRejected, match=message):
        buffer().add_condition(SYSTEM, T, **kwargs)  # type: ignore[arg-type]


def test_unavailable_marks_every_item_and_skips_the_already_unavailable() -> None:
    buf = buffer(size=1024)
    added = buf.add_unavailable(CATALOG.items, T)
    assert len(added) == len(CATALOG.items)
    assert all(e.unavailable for e in buf.current()[0])
    assert buf.add_unavailable(CATALOG.items, T) == []


# --- /sample ----------------------------------------------------------------------------------


def test_sample_from_and_count_walk_forward_and_say_where_to_go_on() -> None:
    buf = buffer(size=16)
    fill(buf, 10)
    result = buf.sample(from_=3, count=4)
    assert [e.sequence for e in result.entries] == [3, 4, 5, 6]
    assert result.window.next_sequence == 7 and not result.end_of_buffer
    result = buf.sample(from_=7, count=16)
    assert [e.sequence for e in result.entries] == [7, 8, 9, 10]
    assert result.window.next_sequence == 11 and result.end_of_buffer
    result = buf.sample(from_=11, count=16)
    assert result.entries == [] and result.window.next_sequence == 11
    assert [e.sequence for e in buf.sample(count=2).entries] == [1, 2]  # no from: the oldest held


def test_sample_filters_by_data_item_and_counts_only_matches() -> None:
    buf = buffer(size=32)
    for _ in range(5):
        fill(buf, 1, X)
        fill(buf, 1, Y)
    result = buf.sample(frozenset({Y}), from_=1, count=3)
    assert [e.sequence for e in result.entries] == [2, 4, 6]
    assert result.window.next_sequence == 7


def test_negative_count_walks_back_from_the_newest_or_from() -> None:
    buf = buffer(size=16)
    fill(buf, 10)
    result = buf.sample(count=-3)
    assert [e.sequence for e in result.entries] == [8, 9, 10]
    assert result.window.next_sequence == 7  # from=7&count=-3 goes on back
    assert [e.sequence for e in buf.sample(from_=7, count=-3).entries] == [5, 6, 7]
    result = buf.sample(from_=2, count=-5)
    assert [e.sequence for e in result.entries] == [1, 2] and result.end_of_buffer


def test_to_returns_the_last_count_up_to_to_inclusive() -> None:
    buf = buffer(size=32)
    fill(buf, 20)
    result = buf.sample(to=15, count=3)
    assert [e.sequence for e in result.entries] == [13, 14, 15]
    assert result.window.next_sequence == 16
    result = buf.sample(from_=12, to=15, count=32)
    assert [e.sequence for e in result.entries] == [12, 13, 14, 15]


@pytest.mark.parametrize(
    ("query", "parameter"),
    [
        ({"from_": 12}, "from"),  # before first_sequence (13)
        ({"from_": 22}, "from"),  # after next_sequence (21)
        ({"count": 0}, "count"),
        ({"count": 9}, "count"),  # more than the buffer holds
        ({"count": -9}, "count"),
        ({"from_": 15, "to": 15}, "to"),  # to must come after from
        ({"to": 22}, "to"),
        ({"to": 12}, "to"),
        ({"to": 18, "count": -2}, "count"),  # with to, count is positive
    ],
)
def test_sample_out_of_range(query: dict[str, int], parameter: str) -> None:
    buf = buffer(size=8)
    fill(buf, 20)
    with pytest.raises(OutOfRange) as caught:
        buf.sample(**query)  # type: ignore[arg-type]
    assert caught.value.code is ErrorCode.OUT_OF_RANGE
    assert caught.value.parameter == parameter and parameter in caught.value.message


@pytest.mark.parametrize("at", [12, 21, 0])
def test_current_at_out_of_range(at: int) -> None:
    buf = buffer(size=8)
    fill(buf, 20)
    with pytest.raises(OutOfRange, match="'at' must be in \\[13, 20\\]"):
        buf.current(at=at)


def test_current_at_gives_the_state_of_that_moment_and_where_to_go_on() -> None:
    buf = buffer(size=8, checkpoint_every=3)
    entries = fill(buf, 6, X) + fill(buf, 4, Y)  # X 1..6, Y 7..10; first_sequence = 3
    state, window = buf.current(at=5)
    assert [e.sequence for e in state] == [5]  # X as of 5; Y not yet seen
    assert window.next_sequence == 6 and window.last_sequence == 10
    state, _ = buf.current(at=8)
    assert [(e.item_id, e.sequence) for e in state] == [(X, 6), (Y, 8)]
    assert buf.current(at=10)[0] == buf.current()[0]
    assert entries[9].sequence == 10


# --- at= against a replay of everything --------------------------------------------------------

ITEMS = [X, Y, EXEC, SYSTEM]
operations = st.lists(
    st.tuples(st.sampled_from(ITEMS), st.integers(0, 3)),
    min_size=1,
    max_size=80,
)


def apply(buf: ObservationBuffer, item: str, choice: int) -> None:
    if item == SYSTEM:
        level = ["NORMAL", "WARNING", "FAULT", "UNAVAILABLE"][choice]
        buf.add_condition(item, T, level, native_code=f"E{choice % 2}" if choice in (1, 2) else None)
    elif item == EXEC:
        buf.add_value(item, T, ["ACTIVE", "READY", "STOPPED", None][choice])
    else:
        buf.add_value(item, T, choice)


@settings(max_examples=150, deadline=None)
@given(operations, st.integers(1, 12), st.integers(1, 7))
def test_current_at_every_sequence_equals_a_replay(ops: list[tuple[str, int]], size: int, every: int) -> None:
    buf = buffer(size=size, checkpoint_every=every)
    everything: list[Entry] = []
    for item, choice in ops:
        before = buf.next_sequence
        apply(buf, item, choice)
        if buf.next_sequence != before:
            entry = buf.get(before)
            assert entry is not None
            everything.append(entry)
    assert [e.sequence for e in everything] == list(range(1, buf.next_sequence))
    for at in range(buf.first_sequence, buf.next_sequence):
        replay = Checkpoint()
        for entry in everything[:at]:
            replay.apply(entry)
        assert buf.current(at=at)[0] == replay.entries(CATALOG), f"at={at}"


def test_the_buffer_needs_a_sane_size_and_instance_id() -> None:
    with pytest.raises(ValueError):
        ObservationBuffer(CATALOG, instance_id=0)
    with pytest.raises(ValueError):
        ObservationBuffer(CATALOG, instance_id=1, size=0)
    assert ObservationBuffer(shop(1, 10), instance_id=1).size == 131_072
    assert laser(3).name == "laser3"

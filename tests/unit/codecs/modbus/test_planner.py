"""The request planner: coalescing within the device's limits and the gap, per table, isolation; and
Hypothesis: every plan reads every field, within the limits, and no two requests could have been one."""

import itertools

from hypothesis import given
from hypothesis import strategies as st

from gateway.codecs.modbus.address import Field, Kind, Order, Table
from gateway.codecs.modbus.planner import Limits, plan


def reg(start: int, kind: Kind = Kind.FLOAT32, table: Table = Table.HOLDING) -> Field:
    return Field(table, start, kind.registers, kind, Order.ABCD)


def coil(start: int) -> Field:
    return Field(Table.COIL, start, 1, Kind.BOOL)


def spans(requests: list) -> list[tuple[str, int, int]]:  # type: ignore[type-arg]
    return [(r.table.value, r.start, r.count) for r in requests]


def test_contiguous_and_nearly_contiguous_fields_become_one_request() -> None:
    fields = [(i, reg(2 * i)) for i in range(10)] + [("far", reg(100)), ("gap", reg(25))]
    requests = plan(fields, Limits(max_gap=5))
    assert spans(requests) == [("holding", 0, 27), ("holding", 100, 2)]
    first = requests[0]
    assert [(k, off) for k, _, off in first.fields][-1] == ("gap", 25)
    assert first.function == 3
    assert first.describe() == "FC3  holding:0-26 (27 registers, 11 variables)"


def test_a_request_never_passes_the_limits() -> None:
    fields = [(i, reg(2 * i)) for i in range(100)]  # 200 contiguous registers
    assert spans(plan(fields)) == [("holding", 0, 124), ("holding", 124, 76)]  # no float cut in two
    assert spans(plan(fields, Limits(max_registers=10))) == [("holding", s, 10) for s in range(0, 200, 10)]
    coils = [(i, coil(i)) for i in range(4500)]
    assert spans(plan(coils)) == [("coil", 0, 2000), ("coil", 2000, 2000), ("coil", 4000, 500)]


def test_tables_are_planned_apart_and_with_their_own_function() -> None:
    fields = [
        ("h", reg(0)),
        ("i", reg(0, table=Table.INPUT)),
        ("c", coil(0)),
        ("d", Field(Table.DISCRETE, 0, 1, Kind.BOOL)),
    ]
    requests = plan(fields)
    assert sorted((r.table.value, r.function) for r in requests) == [
        ("coil", 1),
        ("discrete", 2),
        ("holding", 3),
        ("input", 4),
    ]


def test_bits_of_one_register_share_it_and_isolated_fields_stand_alone() -> None:
    bits = [(b, Field(Table.HOLDING, 7, 1, Kind.BIT, bit=b)) for b in range(16)]
    assert spans(plan(bits)) == [("holding", 7, 1)]
    fields = [(i, reg(2 * i)) for i in range(5)]
    assert spans(plan(fields, isolated={2})) == [("holding", 0, 4), ("holding", 4, 2), ("holding", 6, 4)]
    assert spans(plan(fields, Limits(max_gap=0))) == [("holding", 0, 10)]
    assert spans(plan([(0, reg(0)), (1, reg(3))], Limits(max_gap=0))) == [
        ("holding", 0, 2),
        ("holding", 3, 2),
    ]


KINDS = [Kind.UINT16, Kind.FLOAT32, Kind.FLOAT64, Kind.INT64]


@st.composite
def fields_and_limits(draw: st.DrawFn) -> tuple[list[tuple[int, Field]], Limits, set[int]]:
    n = draw(st.integers(0, 60))
    out = []
    for i in range(n):
        table = draw(st.sampled_from(list(Table)))
        start = draw(st.integers(0, 400))
        if table.bits:
            out.append((i, Field(table, start, 1, Kind.BOOL)))
        else:
            kind = draw(st.sampled_from(KINDS))
            out.append((i, Field(table, start, kind.registers, kind)))
    limits = Limits(
        max_registers=draw(st.integers(4, 125)),
        max_bits=draw(st.integers(1, 2000)),
        max_gap=draw(st.integers(0, 40)),
        max_bit_gap=draw(st.integers(0, 300)),
    )
    isolated = set(draw(st.lists(st.integers(0, max(n - 1, 0)), max_size=3)))
    return out, limits, isolated


@given(fields_and_limits())
def test_every_plan_reads_every_field_within_the_limits(
    case: tuple[list[tuple[int, Field]], Limits, set[int]],
) -> None:
    fields, limits, isolated = case
    requests = plan(fields, limits, isolated)
    seen = []
    for r in requests:
        assert 1 <= r.count <= limits.size(r.table)
        for key, f, offset in r.fields:
            assert f.table is r.table and r.start <= f.start and f.end <= r.end
            assert offset == f.start - r.start
            seen.append(key)
        if any(k in isolated for k, _, _ in r.fields):
            assert len(r.fields) == 1
    assert sorted(seen) == sorted(k for k, _ in fields)
    if isolated:
        return
    # greedy is tight: the next request of a table could not have been taken into the one before
    for a, b in itertools.pairwise(requests):
        if a.table is b.table:
            first = min((f for _, f, _ in b.fields), key=lambda f: (f.start, f.end))
            too_far = first.start - a.end > limits.gap(a.table)
            assert too_far or max(a.end, first.end) - a.start > limits.size(a.table)

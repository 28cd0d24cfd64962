"""Which of a mapping's variables share a controller's memory: the check behind the Modbus and S7 drivers'
"overlaps variables[i]" errors. Pure."""

from __future__ import annotations

from collections.abc import Hashable, Sequence


def overlaps(spans: Sequence[tuple[Hashable, int, int, int | None]]) -> list[tuple[int, int]]:
    """(later, earlier) index pairs of spans `(where, start, end, bit)` that share a unit of one `where`.

    A span with a bit is one bit of its unit: bits may stand beside each other and beside the whole
    unit (a status word and its bits), but the same bit twice may not.
    """
    found: list[tuple[int, int]] = []
    order = sorted(range(len(spans)), key=lambda i: (repr(spans[i][0]), spans[i][1], i))
    active: list[int] = []
    where: Hashable = object()
    for index in order:
        place, start, _end, bit = spans[index]
        if place != where:
            where, active = place, []
        active = [j for j in active if spans[j][2] > start]
        for j in active:
            other_bit = spans[j][3]
            if (bit is None and other_bit is None) or (bit is not None and bit == other_bit):
                found.append((max(index, j), min(index, j)))
        active.append(index)
    return sorted(found)

"""Metric aliases, unique across the whole edge node.

Sparkplug 3.0 (6.4.2): an alias given in an NBIRTH or DBIRTH "MUST be a unique number across this
Edge Node's entire set of metrics", node and devices together; a per-birth check cannot see that,
so the sink takes its aliases from one `Aliases` for the node. Where the specification is silent:
numbers start at 1 and a metric keeps its number for the life of the process, so that a rebirth,
or a device that dies and is born again, binds the same aliases as before.
"""

from __future__ import annotations


class Aliases:
    """Hands out one alias per (device, metric name); `device` None is the node itself."""

    __slots__ = ("_by_key", "_next")

    def __init__(self) -> None:
        self._by_key: dict[tuple[str | None, str], int] = {}
        self._next = 1

    def alias(self, device: str | None, name: str) -> int:
        """The alias of `name` on `device` (or on the node), the same every time it is asked."""
        key = (device, name)
        number = self._by_key.get(key)
        if number is None:
            number = self._by_key[key] = self._next
            self._next += 1
        return number

    def __len__(self) -> int:
        return len(self._by_key)

"""Samples to frames for one target: per-variable encoders built once, frames split at max_cbdata.

This runs for every change, so the per-variable work is prepared up front: the
id, the type and, for fixed-width types, the packed `id | length` header. A
value that cannot be encoded (text the target's encoding cannot represent, a
string too long for a 1-byte length field) is logged once per variable and
left out; the rest of the frame still goes. Bad samples are never sent: the
frame format has no quality field, and a stale value must not look current.
Pure: no I/O, no asyncio.
"""

from __future__ import annotations

import logging
import struct
from collections.abc import Iterable
from typing import Any

from gateway.codecs.copydata import (
    DWDATA_MULTI,
    DWDATA_SINGLE,
    CopydataError,
    Layout,
    Variable,
    VariableTable,
    encode_value,
)
from gateway.codecs.copydata.values import fixed_size
from gateway.model.sample import Sample
from gateway.model.tree import VariableNode
from gateway.sinks.copydata.channel import OutFrame

log = logging.getLogger("gateway.sinks.copydata")


def sendable(sample: Sample) -> bool:
    """Good and Uncertain values go out; Bad ones hold a stale value and do not."""
    return not sample.status.startswith("Bad")


class NodeEncoder:
    """One variable's id, type and (for fixed-width scalars) its prebuilt item header."""

    __slots__ = ("header", "node", "variable")

    def __init__(self, node: VariableNode, variable: Variable, layout: Layout) -> None:
        self.node = node
        self.variable = variable
        size = None if variable.type.array else fixed_size(variable.type.base)
        self.header: bytes | None = layout.header.pack(variable.id, size) if size is not None else None


class TargetEncoder:
    """Builds one target's frames from (node, sample) pairs, and its snapshots from the tree."""

    def __init__(self, name: str, pairs: Iterable[tuple[VariableNode, int]], layout: Layout) -> None:
        self.name = name
        self.layout = layout
        self.encoders: dict[VariableNode, NodeEncoder] = {}
        for node, vid in pairs:
            self.encoders[node] = NodeEncoder(node, Variable(vid, node.path, node.type), layout)
        self.table = VariableTable(e.variable for e in self.encoders.values())
        self.table.check_layout(layout)
        self.by_id: dict[int, VariableNode] = {e.variable.id: n for n, e in self.encoders.items()}
        self.failing: set[VariableNode] = set()  # variables whose latest value could not be encoded
        self.skipped = 0  # values left out for that reason

    def __contains__(self, node: object) -> bool:
        return node in self.encoders

    # --- items ---------------------------------------------------------------------------------

    def item(self, node: VariableNode, value: Any) -> bytes | None:
        """`id | length | data` for one value, or None (logged once) if it cannot be encoded."""
        enc = self.encoders[node]
        layout = self.layout
        try:
            data = encode_value(enc.variable.type, value, layout)
            header = enc.header if enc.header is not None else layout.header.pack(enc.variable.id, len(data))
        except CopydataError as exc:
            self._failed(node, str(exc))
            return None
        except struct.error:
            self._failed(
                node,
                f"{len(data)} bytes do not fit a {layout.len_width}-byte length field "
                f"(max {layout.max_length})",
            )
            return None
        if len(header) + len(data) > layout.max_cbdata:
            self._failed(node, f"{len(data)} bytes are more than max_cbdata {layout.max_cbdata} allows")
            return None
        if node in self.failing:
            self.failing.discard(node)
            log.info("copydata %s: %s is sent again", self.name, node.full_path)
        return header + data

    def _failed(self, node: VariableNode, reason: str) -> None:
        """Count the value as skipped and say so once per variable; the item is left out (None)."""
        self.skipped += 1
        if node not in self.failing:
            self.failing.add(node)
            log.warning("copydata %s: %s is left out of the frames: %s", self.name, node.full_path, reason)

    # --- frames --------------------------------------------------------------------------------

    def single(self, node: VariableNode, sample: Sample) -> OutFrame | None:
        """A dwData=1 frame for one change."""
        item = self.item(node, sample.value)
        return None if item is None else (DWDATA_SINGLE, item)

    def batch(self, changes: Iterable[tuple[VariableNode, Sample]]) -> list[OutFrame]:
        """dwData=2 frames holding these changes, as few as max_cbdata allows (usually one)."""
        frames: list[OutFrame] = []
        parts: list[bytes] = []
        size = 0
        limit = self.layout.max_cbdata
        item_of = self.item
        for node, sample in changes:
            item = item_of(node, sample.value)
            if item is None:
                continue
            if size + len(item) > limit and parts:
                frames.append((DWDATA_MULTI, b"".join(parts)))
                parts, size = [], 0
            parts.append(item)
            size += len(item)
        if parts:
            frames.append((DWDATA_MULTI, b"".join(parts)))
        return frames

    def snapshot(self) -> list[OutFrame]:
        """Every variable's current value (the sendable ones), as dwData=2 frames."""
        return self.batch((node, node.sample) for node in self.encoders if sendable(node.sample))

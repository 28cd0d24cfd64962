from __future__ import annotations

from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import pytest

from gateway.config.loader import load_mapping
from gateway.errors import (
    ControllerRefused,
    ControllerUnavailable,
    NotWritable,
    OutOfRange,
    TypeMismatch,
    UnknownVariable,
)
from gateway.model.context import WriteContext
from gateway.model.sample import ReadBack
from gateway.model.tree import VariableNode, VariableTree

MAPPING = """
machine: m1
driver: {endpoint: "opc.tcp://127.0.0.1:4841"}
variables:
  - {path: Axes/X/Position, source: "ns=2;s=x", type: Double, unit: mm, deadband: 0.5}
  - {path: Axes/X/Counts, source: "ns=2;s=c", type: Double, source_type: Int32,
     scale: {gain: 0.001, offset: 10}, access: readwrite, range: {min: 0, max: 100}}
  - {path: Feed/Override, source: "ns=2;s=o", type: UInt16, access: readwrite, range: {min: 0, max: 150}}
  - {path: Laser/Power, source: "ns=2;s=p", type: Double, range: {min: 0, max: 6000}, deadband: "1%"}
  - {path: Table, source: "ns=2;s=t", type: "Double[]", deadband: 0.1}
  - {path: Name, source: "ns=2;s=n", type: String}
"""

TS = datetime(2026, 11, 21, 12, 0, tzinfo=UTC)
CTX = WriteContext("test")


class Recorder:
    def __init__(self, error: Exception | None = None) -> None:
        self.writes: list[tuple[str, Any]] = []
        self.error = error

    async def write(self, node: VariableNode, raw: Any) -> None:
        if self.error:
            raise self.error
        self.writes.append((node.path, raw))


@pytest.fixture
def tree(tmp_path: Path) -> VariableTree:
    path = tmp_path / "m1.yaml"
    path.write_text(MAPPING)
    return VariableTree([load_mapping(path).definition()])


def published(tree: VariableTree) -> list[tuple[str, Any, str]]:
    sub = tree.hub.subscriptions[0]
    return [(n.path, s.value, s.status) for n, s in sub.take() if not n.internal]


def test_deadband_drops_small_changes_but_not_slow_drift(tree: VariableTree) -> None:
    tree.hub.subscribe("t", every_change=True)
    m = tree.machines["m1"]
    x = m.nodes["Axes/X/Position"]
    for value in (0.0, 0.2, 0.4, 0.6, 0.7, 1.2):
        m.ingest(x, value, TS)
    assert published(tree) == [
        ("Axes/X/Position", 0.0, "Good"),
        ("Axes/X/Position", 0.6, "Good"),
        ("Axes/X/Position", 1.2, "Good"),
    ]


def test_percent_deadband_is_a_share_of_the_range(tree: VariableTree) -> None:
    tree.hub.subscribe("t", every_change=True)
    m = tree.machines["m1"]
    p = m.nodes["Laser/Power"]
    for value in (1000.0, 1050.0, 1061.0):  # 1 % of 0..6000 = 60 W
        m.ingest(p, value, TS)
    assert [v for _, v, _ in published(tree)] == [1000.0, 1061.0]


def test_array_deadband_and_length_change(tree: VariableTree) -> None:
    tree.hub.subscribe("t", every_change=True)
    m = tree.machines["m1"]
    t = m.nodes["Table"]
    for value in ([1.0, 2.0], [1.05, 2.0], [1.2, 2.0], [1.2, 2.0, 3.0]):
        m.ingest(t, value, TS)
    assert [v for _, v, _ in published(tree)] == [[1.0, 2.0], [1.2, 2.0], [1.2, 2.0, 3.0]]


def test_scaling_applies_on_the_way_in_and_is_undone_for_writes(tree: VariableTree) -> None:
    tree.hub.subscribe("t", every_change=True)
    m = tree.machines["m1"]
    counts = m.nodes["Axes/X/Counts"]
    m.ingest(counts, 5000, TS)
    assert counts.sample.value == pytest.approx(15.0)
    assert counts.to_raw(15.0) == 5000 and isinstance(counts.to_raw(15.0), int)


def test_quality_changes_are_published_and_keep_the_last_value(tree: VariableTree) -> None:
    tree.hub.subscribe("t", every_change=True)
    m = tree.machines["m1"]
    x = m.nodes["Axes/X/Position"]
    m.ingest(x, 3.0, TS)
    m.invalidate("BadNotConnected", "connection refused")
    m.invalidate("BadNotConnected", "connection refused")  # no duplicate
    m.ingest(x, 3.0, TS)  # same value, but Good again: published
    rows = [r for r in published(tree) if r[0] == "Axes/X/Position"]
    assert rows == [
        ("Axes/X/Position", 3.0, "Good"),
        ("Axes/X/Position", 3.0, "BadNotConnected"),
        ("Axes/X/Position", 3.0, "Good"),
    ]
    assert x.sample.reason == ""


def test_ingest_of_a_wrong_controller_type_marks_the_variable_bad(tree: VariableTree) -> None:
    m = tree.machines["m1"]
    counts = m.nodes["Axes/X/Counts"]
    m.ingest(counts, "abc", TS)
    assert counts.sample.status == "BadTypeMismatch"


async def test_write_reaches_the_source_unscaled(tree: VariableTree) -> None:
    m = tree.machines["m1"]
    m.writer = rec = Recorder()
    await m.write("Axes/X/Counts", 20.0, CTX)
    await tree.write("m1", "Feed/Override", 80, CTX)
    assert rec.writes == [("Axes/X/Counts", 10000), ("Feed/Override", 80)]


@pytest.mark.parametrize(
    ("path", "value", "error"),
    [
        ("Axes/X/Position", 1.0, NotWritable),
        ("Status/Connected", True, NotWritable),
        ("Feed/Override", 151, OutOfRange),
        ("Feed/Override", -1, OutOfRange),
        ("Feed/Override", "80", TypeMismatch),
        ("Feed/Override", 80.5, TypeMismatch),
        ("Axes/X/Counts", 101.0, OutOfRange),
        ("No/Such", 1, UnknownVariable),
    ],
)
async def test_refused_writes_never_reach_the_source(
    tree: VariableTree, path: str, value: Any, error: type
) -> None:
    m = tree.machines["m1"]
    m.writer = rec = Recorder()
    with pytest.raises(error) as info:
        await m.write(path, value, CTX)
    assert info.value.reason
    assert rec.writes == []


async def test_write_without_a_controller_and_controller_refusal(tree: VariableTree) -> None:
    m = tree.machines["m1"]
    with pytest.raises(ControllerUnavailable):
        await m.write("Feed/Override", 80, CTX)
    m.writer = Recorder(ControllerRefused("no", status="BadNotWritable"))
    with pytest.raises(ControllerRefused) as info:
        await m.write("Feed/Override", 80, CTX)
    assert info.value.status == "BadNotWritable"


async def test_write_hooks_can_refuse(tree: VariableTree) -> None:
    from gateway.errors import AccessDenied

    async def deny(node: VariableNode, value: Any, ctx: WriteContext) -> None:
        raise AccessDenied(f"{ctx.user} may not write {node.path}")

    tree.write_hooks.append(deny)
    m = tree.machines["m1"]
    m.writer = rec = Recorder()
    with pytest.raises(AccessDenied):
        await m.write("Feed/Override", 80, WriteContext("opcua", user="viewer"))
    assert rec.writes == []


class ReadingBack:
    """A source that reads the written value back from the controller, stamped `at`."""

    def __init__(self, at: datetime, hold: float = 60.0) -> None:
        self.at = at
        self.hold = hold

    async def write(self, node: VariableNode, raw: Any) -> ReadBack:
        return ReadBack(raw, self.at, hold=self.hold)


def later(seconds: float) -> datetime:
    return TS + timedelta(seconds=seconds)


async def test_a_write_is_answered_with_the_read_back_already_in_the_tree(tree: VariableTree) -> None:
    m = tree.machines["m1"]
    counts = m.nodes["Axes/X/Counts"]
    m.ingest(counts, 0, TS)
    tree.hub.subscribe("t", every_change=True)
    m.writer = ReadingBack(later(1))
    await m.write("Axes/X/Counts", 20.0, CTX)
    assert (counts.sample.value, counts.sample.source_ts, counts.sample.status) == (20.0, later(1), "Good")
    assert published(tree) == [("Axes/X/Counts", 20.0, "Good")]


async def test_a_notification_older_than_the_read_back_does_not_undo_it(tree: VariableTree) -> None:
    m = tree.machines["m1"]
    override = m.nodes["Feed/Override"]
    m.ingest(override, 100, TS)
    m.writer = ReadingBack(later(2))
    await m.write("Feed/Override", 50, CTX)
    m.ingest(override, 100, later(1))  # sampled before the write, delivered after its answer
    assert override.sample.value == 50
    m.ingest(override, 60, later(3))  # the controller's next change
    assert (override.sample.value, override.sample.source_ts) == (60, later(3))
    m.ingest(override, 70, later(1))  # the hold ended with the first newer notification
    assert override.sample.value == 70


async def test_the_hold_on_older_notifications_ends_with_its_time(tree: VariableTree) -> None:
    m = tree.machines["m1"]
    override = m.nodes["Feed/Override"]
    m.writer = ReadingBack(later(2), hold=0.0)  # a controller whose clock stepped back must not freeze it
    await m.write("Feed/Override", 50, CTX)
    m.ingest(override, 100, later(1))
    assert override.sample.value == 100


def test_a_bad_or_older_read_back_changes_nothing(tree: VariableTree) -> None:
    m = tree.machines["m1"]
    override = m.nodes["Feed/Override"]
    m.ingest(override, 100, later(5))
    m.confirm(override, ReadBack(50, later(4)))
    m.confirm(override, ReadBack(None, later(6), "BadNotReadable", "write-only"))
    sample = override.sample
    assert (sample.value, sample.status, sample.source_ts) == (100, "Good", later(5))
    m.ingest(override, 90, later(4.5))  # neither set a hold
    assert override.sample.value == 90


def test_status_variables_track_the_connection(tree: VariableTree) -> None:
    m = tree.machines["m1"]
    st = m.status
    assert st.state == "disconnected" and not st.is_connected
    st.connecting()
    st.connected()
    assert st.is_connected and st.reconnects == 0
    st.disconnected("connection refused")
    st.connected()
    assert st.reconnects == 1 and st.last_error == "connection refused"
    assert m.nodes["Status/State"].sample.value == "connected"


def test_the_machine_counts_what_it_publishes_to_the_hub(tree: VariableTree) -> None:
    m = tree.machines["m1"]
    node = m.nodes["Name"]
    every = tree.hub.subscribe("every", every_change=True)
    before = m.changes
    m.ingest(node, "a.nc", TS)
    m.ingest(node, "a.nc", TS)  # no change: not published, not counted
    m.ingest(node, "b.nc", TS)
    m.invalidate("BadNotConnected", "gone")  # every mapped variable turns bad, and the status says why
    published = every.take()
    assert m.changes - before == len(published)
    assert sum(1 for n, _ in published if n is node) == 3

"""The receive path, fed with PublishResponses encoded by asyncua (no network needed).

Each response goes through gateway.sources.opcua.publish_decode as one off the wire would, once read by the
compiled reader and once by asyncua's decoding (every test runs on both paths).
"""

from datetime import UTC, datetime
from typing import Any

import pytest
from asyncua import ua
from asyncua.common.utils import Buffer
from asyncua.ua.ua_binary import struct_to_binary

from gateway.config.mapping import MachineMapping
from gateway.model.tree import Machine, VariableTree
from gateway.sources.opcua import publish_decode
from gateway.sources.opcua.client import OpcUaSource
from gateway.sources.opcua.publish_decode import decode

TS = datetime(2024, 5, 6, 7, 8, 9, tzinfo=UTC)
SERVER_TS = datetime(2024, 5, 6, 7, 8, 10, tzinfo=UTC)


@pytest.fixture(autouse=True, params=["compiled", "asyncua"])
def decoding(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    """Both ways of reading a PublishResponse: the compiled reader, and asyncua's decoding."""
    if request.param == "compiled" and publish_decode.compiled is None:
        pytest.skip("the compiled reader is not built here")
    monkeypatch.setattr(publish_decode, "PURE", request.param == "asyncua")
    return str(request.param)


def make_source() -> tuple[OpcUaSource, Machine]:
    mapping = MachineMapping.model_validate(
        {
            "machine": "m",
            "driver": {"endpoint": "opc.tcp://127.0.0.1:1/x"},
            "variables": [
                {"path": "Pos", "source": "ns=2;s=Pos", "type": "Double"},
                {"path": "Name", "source": "ns=2;s=Name", "type": "String"},
                {"path": "Ids", "source": "ns=2;s=Ids", "type": "UInt32[]"},
                {"path": "Count", "source": "ns=2;i=7", "type": "Int32"},
                {"path": "Broken", "source": "no node id", "type": "Int32"},
            ],
        }
    )
    machine = VariableTree([mapping.definition()]).machines["m"]
    return OpcUaSource(machine, mapping), machine


def handle(source: OpcUaSource, path: str) -> int:
    return next(h for h, (node, _) in source._handles.items() if node.path == path)


def change(
    source: OpcUaSource, path: str, value: Any, *, status: int = 0, ts: Any = TS, server_ts: Any = None
) -> ua.MonitoredItemNotification:
    dv = ua.DataValue(
        Value=value if value is None or isinstance(value, ua.Variant) else ua.Variant(value),
        StatusCode=ua.StatusCode(status),
        SourceTimestamp=ts,
        ServerTimestamp=server_ts,
    )
    return ua.MonitoredItemNotification(ClientHandle=handle(source, path), Value=dv)


def receive(source: OpcUaSource, *notifications: Any) -> list[tuple[str, str]]:
    """Encode a PublishResponse carrying `notifications`, decode it as the source does, process it."""
    response = ua.PublishResponse()
    response.Parameters.NotificationMessage.NotificationData = list(notifications)
    published = decode(Buffer(struct_to_binary(response)))
    lost: list[tuple[str, str]] = []
    source._process(published.changes, published.statuses, lambda s, r: lost.append((s, r)))
    return lost


def feed(source: OpcUaSource, *items: ua.MonitoredItemNotification) -> list[tuple[str, str]]:
    return receive(source, ua.DataChangeNotification(MonitoredItems=list(items)))


def test_values_reach_the_tree_with_their_source_timestamp() -> None:
    source, machine = make_source()
    feed(
        source, change(source, "Pos", 12.5), change(source, "Name", "part.nc"), change(source, "Ids", [3, 7])
    )
    assert machine.nodes["Pos"].sample.value == 12.5
    assert machine.nodes["Pos"].sample.source_ts == TS
    assert machine.nodes["Pos"].sample.status == "Good"
    assert machine.nodes["Name"].sample.value == "part.nc"
    assert machine.nodes["Ids"].sample.value == [3, 7]


def test_missing_source_timestamp_falls_back_to_server_time_then_now() -> None:
    source, machine = make_source()
    feed(source, change(source, "Pos", 1.0, ts=None, server_ts=SERVER_TS))
    assert machine.nodes["Pos"].sample.source_ts == SERVER_TS
    before = datetime.now(UTC)
    feed(source, change(source, "Count", 3, ts=None))
    ts = machine.nodes["Count"].sample.source_ts
    assert ts.tzinfo is not None and ts >= before


def test_uncertain_passes_through_with_its_value_and_bad_keeps_the_last_value() -> None:
    source, machine = make_source()
    feed(source, change(source, "Pos", 5.0))
    feed(source, change(source, "Pos", 6.0, status=ua.StatusCodes.UncertainLastUsableValue))
    assert machine.nodes["Pos"].sample.status == "UncertainLastUsableValue"
    assert machine.nodes["Pos"].sample.value == 6.0
    feed(source, change(source, "Pos", None, status=ua.StatusCodes.BadSensorFailure))
    sample = machine.nodes["Pos"].sample
    assert sample.status == "BadSensorFailure"
    assert sample.value == 6.0
    assert "BadSensorFailure" in sample.reason


def test_values_of_another_type_are_converted_or_rejected_with_a_reason() -> None:
    source, machine = make_source()
    feed(source, change(source, "Pos", ua.Variant(7, ua.VariantType.Int32)))
    assert machine.nodes["Pos"].sample.value == 7.0
    assert type(machine.nodes["Pos"].sample.value) is float
    feed(source, change(source, "Count", "seven"))
    sample = machine.nodes["Count"].sample
    assert sample.status == "BadTypeMismatch"
    assert "str" in sample.reason and "Int32" in sample.reason
    feed(source, change(source, "Count", True))
    assert machine.nodes["Count"].sample.status == "BadTypeMismatch"
    feed(source, change(source, "Name", ua.Variant(None, ua.VariantType.String)))
    assert machine.nodes["Name"].sample.value == ""
    assert machine.nodes["Name"].sample.good


def test_unknown_handles_are_ignored() -> None:
    source, machine = make_source()
    stray = ua.MonitoredItemNotification(ClientHandle=999, Value=ua.DataValue(ua.Variant(1.0)))
    feed(source, stray, change(source, "Pos", 2.0))
    assert machine.nodes["Pos"].sample.value == 2.0


def test_an_unparseable_address_gets_no_handle() -> None:
    source, _machine = make_source()
    assert all(node.path != "Broken" for node, _ in source._handles.values())
    assert "Broken" in {n.path for n in source._address_errors}


def test_server_shutdown_status_change_reports_the_loss() -> None:
    source, _ = make_source()
    notification = ua.StatusChangeNotification(Status=ua.StatusCode(ua.StatusCodes.BadShutdown))
    lost = receive(source, notification)
    assert lost == [("BadNotConnected", "server shut down")]

"""NCMD and DCMD: writes by alias or name with typed values, the rebirth request, and every refusal,
on payloads that an independent host encoder builds."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.codecs.sparkplug import (
    REBIRTH,
    BadBirth,
    BadCommand,
    BadValue,
    Definition,
    MalformedPayload,
    Metric,
    MetricTable,
    UnknownAlias,
    UnknownMetric,
    WrongDatatype,
    decode_dcmd,
    decode_ncmd,
    sparkplug_type,
)
from gateway.codecs.sparkplug.sparkplug_b_pb2 import Payload
from gateway.model.types import TypeSpec
from tests.unit.codecs.sparkplug import host
from tests.unit.codecs.sparkplug.strategies import ALL_SPECS, same, values

T = TypeSpec.parse
DEVICE = MetricTable([
    Definition("Axes/X/Position", T("Double"), 10),
    Definition("Feed/Override", T("UInt16"), 11),
    Definition("Laser/On", T("Boolean"), 12),
    Definition("Program/Name", T("String"), 13),
    Definition("ActiveAlarms/Codes", T("Int32[]"), 14),
    Definition("Counter", T("UInt32"), 15),
    Definition("Named/Only", T("Int16")),
])  # fmt: skip
NODE = MetricTable([Definition("Gateway/Version", T("String"), 1)])


def test_a_write_by_alias() -> None:
    command = decode_dcmd(host.command(host.write(50, host.UINT16, alias=11), timestamp=123), DEVICE)
    assert command.refusals == () and command.rebirth is False and command.timestamp == 123
    (write,) = command.writes
    assert (write.metric.name, write.metric.alias, write.value) == ("Feed/Override", 11, 50)


def test_a_write_by_name_and_with_both_name_and_alias() -> None:
    command = decode_dcmd(
        host.command(
            host.write(True, host.BOOLEAN, name="Laser/On"),
            host.write(-3, host.INT16, name="Named/Only", send_datatype=True),
            host.write("demo.nc", host.STRING, alias=13, name="Program/Name"),
        ),
        DEVICE,
    )
    assert command.refusals == ()
    assert [(w.metric.name, w.value) for w in command.writes] == [
        ("Laser/On", True), ("Named/Only", -3), ("Program/Name", "demo.nc")
    ]  # fmt: skip


def test_a_metric_timestamp_comes_along() -> None:
    metric = host.write(1.5, host.DOUBLE, alias=10)
    metric.timestamp = 42
    assert decode_dcmd(host.command(metric, timestamp=None), DEVICE).writes[0].timestamp == 42
    assert decode_dcmd(host.command(metric, timestamp=None), DEVICE).timestamp is None


@pytest.mark.parametrize("spec", ALL_SPECS, ids=str)
@given(data=st.data())
def test_every_type_is_read_from_a_host_write(spec: TypeSpec, data: st.DataObject) -> None:
    value = data.draw(values(spec), label="value")
    by_alias = data.draw(st.booleans(), label="by_alias")
    table = MetricTable([Definition("Some/Path", spec, 7)])
    datatype = int(sparkplug_type(spec))
    metric = (
        host.write(value, datatype, alias=7) if by_alias else host.write(value, datatype, name="Some/Path")
    )
    command = decode_dcmd(host.command(metric), table)
    assert command.refusals == ()
    assert same(command.writes[0].value, value)


def test_ncmd_rebirth_request() -> None:
    command = decode_ncmd(host.command(host.write(True, host.BOOLEAN, name=REBIRTH)), NODE)
    assert command.rebirth is True and command.writes == () and command.refusals == ()
    typed = host.write(True, host.BOOLEAN, name=REBIRTH, send_datatype=True)
    assert decode_ncmd(host.command(typed), NODE).rebirth is True


def test_ncmd_writes_node_metrics_beside_a_rebirth() -> None:
    command = decode_ncmd(
        host.command(host.write("x", host.STRING, alias=1), host.write(True, host.BOOLEAN, name=REBIRTH)),
        NODE,
    )
    assert command.rebirth and [w.metric.name for w in command.writes] == ["Gateway/Version"]


@pytest.mark.parametrize(
    ("metric", "error", "fragment"),
    [
        (host.write(False, host.BOOLEAN, name=REBIRTH), BadCommand, "false asks for nothing"),
        (
            host.write(1, host.INT32, name=REBIRTH),
            WrongDatatype,
            "a rebirth request is a Boolean true, got int_value",
        ),
    ],
)
def test_rebirth_requests_that_ask_for_nothing(metric: Payload.Metric, error: type, fragment: str) -> None:
    command = decode_ncmd(host.command(metric), NODE)
    assert command.rebirth is False and command.writes == ()
    (refusal,) = command.refusals
    assert isinstance(refusal, error) and fragment in str(refusal) and refusal.metric == REBIRTH


def test_rebirth_with_a_wrong_datatype_is_refused() -> None:
    metric = host.write(True, host.BOOLEAN, name=REBIRTH)
    metric.datatype = host.INT8
    (refusal,) = decode_ncmd(host.command(metric), NODE).refusals
    assert isinstance(refusal, WrongDatatype) and "the command says Int8" in str(refusal)


def test_rebirth_is_by_name_only_and_only_in_ncmd() -> None:
    by_alias = decode_ncmd(host.command(host.write(True, host.BOOLEAN, alias=99)), NODE)
    assert not by_alias.rebirth and isinstance(by_alias.refusals[0], UnknownAlias)
    in_dcmd = decode_dcmd(host.command(host.write(True, host.BOOLEAN, name=REBIRTH)), DEVICE)
    assert not in_dcmd.rebirth and isinstance(in_dcmd.refusals[0], UnknownMetric)


def _refusal(metric: Payload.Metric) -> Exception:
    command = decode_dcmd(host.command(metric), DEVICE)
    assert command.writes == () and command.rebirth is False
    (refusal,) = command.refusals
    return refusal


def _with(metric: Payload.Metric, **fields: object) -> Payload.Metric:
    for key, value in fields.items():
        setattr(metric, key, value)
    return metric


@pytest.mark.parametrize(
    ("metric", "error", "text"),
    [
        (host.write(5, host.UINT16, alias=99), UnknownAlias,
         "alias 99: the birth bound no metric to this alias"),
        (host.write(5, host.UINT16, name="Feed/override"), UnknownMetric,
         "Feed/override: the birth announced no metric of this name"),
        (host.write(5, host.UINT16), UnknownMetric, "a metric: the metric has neither an alias nor a name"),
        (host.write(5, host.UINT16, alias=11, name="Laser/On"), BadValue,
         "alias 11: alias 11 is 'Feed/Override', the name says 'Laser/On'"),
        (host.write(5, host.INT32, alias=11, send_datatype=True), WrongDatatype,
         "Feed/Override: the birth says UInt16, the command says Int32"),
        (_with(host.write(5, host.UINT16, alias=11), datatype=999), WrongDatatype,
         "the command says datatype 999 (not a Sparkplug type)"),
        (host.write(5.0, host.DOUBLE, alias=11), WrongDatatype,
         "Feed/Override: a UInt16 travels in int_value, got double_value"),
        (host.write("50", host.STRING, alias=11), WrongDatatype, "got string_value"),
        (host.write(1, host.UINT8, alias=12), WrongDatatype, "Laser/On: a Boolean travels in boolean_value"),
        (host.write(1.5, host.FLOAT, alias=10), WrongDatatype,
         "Axes/X/Position: a Double travels in double_value"),
        (host.write(70000, host.UINT32, alias=11), BadValue,
         "Feed/Override: 70000 does not fit a UInt16 (0..65535)"),
        (_with(Payload.Metric(alias=11), is_null=True), BadValue, "Feed/Override: a null cannot be written"),
        (Payload.Metric(alias=11), BadValue, "Feed/Override: no value; a UInt16 in int_value is needed"),
        (_with(host.write(5, host.UINT16, alias=11), is_historical=True), BadCommand,
         "a value marked historical cannot be written"),
        (_with(Payload.Metric(alias=14), bytes_value=b"\x01\x02"), BadValue,
         "ActiveAlarms/Codes: an Int32Array is 4-byte values"),
        (_with(Payload.Metric(alias=14), int_value=3), WrongDatatype,
         "an Int32Array travels in bytes_value, got int_value"),
        (Payload.Metric(alias=13, dataset_value=Payload.DataSet(num_of_columns=1)), WrongDatatype,
         "got dataset_value"),
    ],
)  # fmt: skip
def test_each_bad_metric_is_refused_with_its_reason(metric: Payload.Metric, error: type, text: str) -> None:
    refusal = _refusal(metric)
    assert isinstance(refusal, error)
    assert text in str(refusal)


def test_uint32_sent_in_long_value_is_accepted() -> None:
    metric = Payload.Metric(alias=15, long_value=4_000_000_000)
    assert decode_dcmd(host.command(metric), DEVICE).writes[0].value == 4_000_000_000


def test_good_metrics_are_kept_beside_bad_ones() -> None:
    command = decode_dcmd(
        host.command(
            host.write(50, host.UINT16, alias=11),
            host.write(5, host.UINT16, alias=99),
            host.write("x", host.STRING, alias=12),
            host.write(True, host.BOOLEAN, alias=12),
        ),
        DEVICE,
    )
    assert [(w.metric.name, w.value) for w in command.writes] == [("Feed/Override", 50), ("Laser/On", True)]
    assert [type(r) for r in command.refusals] == [UnknownAlias, WrongDatatype]


def test_a_command_without_metrics_is_refused() -> None:
    (refusal,) = decode_dcmd(host.command(), DEVICE).refusals
    assert isinstance(refusal, BadCommand) and "no metrics" in str(refusal) and refusal.metric is None


def test_bytes_that_are_no_payload_raise() -> None:
    with pytest.raises(MalformedPayload, match="not a Sparkplug B protobuf payload"):
        decode_dcmd(b"\x12\x05abc", DEVICE)
    with pytest.raises(MalformedPayload, match="more than the 8 this edge node reads"):
        decode_dcmd(host.command(host.write(50, host.UINT16, alias=11)), DEVICE, limit=8)


def test_the_table_comes_from_the_births_metrics() -> None:
    table = MetricTable.from_metrics(
        [Metric("A", T("Int16"), 1, 0, alias=4), Metric("B", T("Double"), 1.0, 0)]
    )
    assert [(d.name, d.alias, str(d.spec)) for d in table] == [("A", 4, "Int16"), ("B", None, "Double")]
    assert table.by_alias(4) is not None and table.by_name("B") is not None and len(table) == 2
    with pytest.raises(BadBirth, match="alias 4 is also 'A'"):
        MetricTable([Definition("A", T("Int16"), 4), Definition("B", T("Int16"), 4)])
    with pytest.raises(BadBirth, match="appears twice"):
        MetricTable([Definition("A", T("Int16"), 4), Definition("A", T("Int16"), 5)])

"""Births, data and deaths: the shape Sparkplug 3.0 prescribes, read back by an independent host."""

from __future__ import annotations

from datetime import UTC, datetime

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.codecs.sparkplug import (
    BDSEQ,
    REBIRTH,
    Aliases,
    BadBirth,
    BdSeq,
    Definition,
    MalformedPayload,
    Metric,
    MetricTable,
    Property,
    Quality,
    Released,
    Seq,
    SparkplugType,
    Unencodable,
    decode_dcmd,
    decode_ncmd,
    encode_command,
    encode_dbirth,
    encode_ddata,
    encode_ddeath,
    encode_nbirth,
    encode_ndata,
    encode_ndeath,
    encode_stored,
    metric_properties,
    quality_of_status,
    release_stored,
    sparkplug_type,
)
from gateway.codecs.sparkplug.sparkplug_b_pb2 import Payload
from gateway.model.types import TypeSpec
from tests.unit.codecs.sparkplug import host
from tests.unit.codecs.sparkplug.strategies import ALL_SPECS, same, values

T = TypeSpec.parse
NOW = 1_700_000_000_000

NODE = [
    Metric("Gateway/Version", T("String"), "0.1.0", NOW - 5, alias=1),
    Metric("Gateway/Machines", T("UInt32"), 2, NOW - 5, alias=2),
]
LASER = [
    Metric("Axes/X/Position", T("Double"), 12.5, NOW - 30, alias=10,
           properties=metric_properties(unit="mm", low=0, high=3000, description="Actual X position")),
    Metric("Feed/Override", T("UInt16"), 100, NOW - 20, alias=11,
           properties=metric_properties(unit="%", low=0, high=150, read_only=False)),
    Metric("ActiveAlarms/Codes", T("Int32[]"), [17, -4], NOW - 10, alias=12),
    Metric("Program/Name", T("String"), None, NOW - 40, alias=13),
]  # fmt: skip
TYPES = {m.alias: int(m.datatype) for m in NODE + LASER if m.alias is not None}


def test_nbirth_has_seq_zero_the_bdseq_and_the_rebirth_metric() -> None:
    seq = Seq()
    seq.next(), seq.next()  # whatever came before, a birth starts the count again
    seen = host.read(encode_nbirth(NODE, bdseq=7, seq=seq, timestamp=NOW))
    assert seen.seq == 0 and seen.timestamp == NOW
    by_name = {m.name: m for m in seen.metrics}
    bdseq = by_name[BDSEQ]
    assert (bdseq.datatype, bdseq.value, bdseq.alias) == (host.INT64, 7, None)
    rebirth = by_name[REBIRTH]
    assert (rebirth.datatype, rebirth.value, rebirth.alias) == (
        host.BOOLEAN,
        False,
        None,
    )  # no alias, by rule
    assert by_name["Gateway/Version"].value == "0.1.0" and by_name["Gateway/Machines"].value == 2
    for metric in seen.metrics:  # name, datatype, timestamp and value, always
        assert metric.name and metric.datatype and metric.timestamp is not None
        assert metric.value is not None or metric.is_null
    assert seq.next() == 1


def test_dbirth_announces_every_metric_with_name_alias_datatype_value_and_properties() -> None:
    seq = Seq()
    encode_nbirth(NODE, bdseq=0, seq=seq, timestamp=NOW)
    seen = host.read(encode_dbirth(LASER, seq=seq, timestamp=NOW))
    assert seen.seq == 1 and seen.timestamp == NOW
    got = {m.name: m for m in seen.metrics}
    for metric in LASER:
        one = got[metric.name]
        assert (one.alias, one.datatype, one.timestamp) == (
            metric.alias,
            int(metric.datatype),
            metric.timestamp,
        )
        assert one.value == metric.value
    assert got["Program/Name"].is_null and got["Program/Name"].value is None
    assert got["Axes/X/Position"].properties == {
        "engUnit": (host.STRING, "mm"), "engLow": (host.DOUBLE, 0.0), "engHigh": (host.DOUBLE, 3000.0),
        "documentation": (host.STRING, "Actual X position"),
    }  # fmt: skip
    assert got["Feed/Override"].properties["readOnly"] == (host.BOOLEAN, False)


def test_births_and_data_list_values_in_time_order() -> None:
    seen = host.read(encode_dbirth(LASER, seq=Seq(), timestamp=NOW))
    stamps = [m.timestamp or 0 for m in seen.metrics]
    assert stamps == sorted(stamps) and len(stamps) == len(LASER) and all(m.timestamp for m in seen.metrics)


def test_ddata_names_metrics_by_alias_only_without_datatype() -> None:
    changed = [
        Metric("Axes/X/Position", T("Double"), 13.25, NOW + 1, alias=10),
        Metric("ActiveAlarms/Codes", T("Int32[]"), [], NOW + 2, alias=12),
    ]
    seen = host.read(encode_ddata(changed, seq=Seq(), timestamp=NOW + 3), TYPES)
    assert [(m.name, m.alias, m.datatype is not None, m.value) for m in seen.metrics] == [
        (None, 10, True, 13.25),
        (None, 12, True, []),
    ]
    raw = Payload.FromString(encode_ddata(changed, seq=Seq(), timestamp=NOW))
    assert not any(m.HasField("datatype") or m.HasField("name") for m in raw.metrics)


def test_a_metric_without_an_alias_is_named_in_data() -> None:
    seen = host.read(encode_ndata([Metric("Gateway/Drops", T("UInt64"), 3, NOW)], seq=Seq(), timestamp=NOW),
                     {"Gateway/Drops": host.UINT64})  # fmt: skip
    assert (seen.metrics[0].name, seen.metrics[0].alias, seen.metrics[0].value) == ("Gateway/Drops", None, 3)


def test_stored_values_go_out_marked_historical() -> None:
    stored = [Metric("Axes/X/Position", T("Double"), float(i), NOW - 1000 + i, alias=10, historical=True)
              for i in range(3)]  # fmt: skip
    live = Metric("Axes/X/Position", T("Double"), 99.0, NOW, alias=10)
    seen = host.read(encode_ddata([live, *stored], seq=Seq(), timestamp=NOW), TYPES)
    assert [(m.value, m.is_historical) for m in seen.metrics] == [
        (0.0, True),
        (1.0, True),
        (2.0, True),
        (99.0, False),
    ]


def test_two_values_of_one_metric_at_one_instant_keep_the_later() -> None:
    batch = [Metric("Feed/Override", T("UInt16"), v, NOW, alias=11) for v in (50, 60, 70)]
    batch.insert(1, Metric("Feed/Override", T("UInt16"), 40, NOW - 1, alias=11))
    seen = host.read(encode_ddata(batch, seq=Seq(), timestamp=NOW), TYPES)
    assert [(m.timestamp, m.value) for m in seen.metrics] == [(NOW - 1, 40), (NOW, 70)]


def test_quality_goes_out_as_the_specifications_int32_property() -> None:
    bad = Metric("Axes/X/Position", T("Double"), 12.5, NOW, alias=10,
                 properties=metric_properties(quality=quality_of_status("BadNotConnected")))  # fmt: skip
    seen = host.read(encode_ddata([bad], seq=Seq(), timestamp=NOW), TYPES)
    assert seen.metrics[0].properties == {"Quality": (3, 0)}  # type 3 (Int32), value 0 (BAD)
    statuses = ("Good", "GoodClamped", "UncertainLastUsableValue", "BadTimeout")
    assert [quality_of_status(s) for s in statuses] == [
        Quality.GOOD,
        Quality.GOOD,
        Quality.STALE,
        Quality.BAD,
    ]
    assert [int(q) for q in (Quality.BAD, Quality.GOOD, Quality.STALE)] == [0, 192, 500]


def test_a_null_property_is_typed_and_flagged() -> None:
    metric = Metric(
        "A", T("Double"), 1.0, NOW, alias=1, properties={"engUnit": Property(SparkplugType.String, None)}
    )
    raw = Payload.FromString(encode_dbirth([metric], seq=Seq(), timestamp=NOW))
    value = raw.metrics[0].properties.values[0]
    assert (value.type, value.is_null, value.WhichOneof("value")) == (12, True, None)


def test_ddeath_has_seq_and_timestamp_and_no_metrics() -> None:
    seq = Seq()
    encode_nbirth([], bdseq=0, seq=seq, timestamp=NOW)
    seen = host.read(encode_ddeath(seq=seq, timestamp=NOW + 5))
    assert (seen.seq, seen.timestamp, seen.metrics) == (1, NOW + 5, [])


def test_ndeath_is_the_bdseq_alone_without_seq() -> None:
    bd = BdSeq()
    will = encode_ndeath(bdseq=bd.connect(), timestamp=NOW)
    birth = host.read(encode_nbirth(NODE, bdseq=bd.current, seq=Seq(), timestamp=NOW + 1))
    death = host.read(will)
    assert death.seq is None and Payload.FromString(will).HasField("seq") is False
    assert [(m.name, m.datatype, m.value) for m in death.metrics] == [(BDSEQ, host.INT64, 0)]
    assert death.metrics[0].value == next(m.value for m in birth.metrics if m.name == BDSEQ)
    assert (
        host.read(encode_ndeath(bdseq=5)).timestamp is None
    )  # the broker sends it; hosts use their own time


# --- counters -------------------------------------------------------------------------------------


def test_seq_runs_across_every_message_of_the_node_and_wraps_after_255() -> None:
    seq = Seq()
    sent = [host.read(encode_nbirth(NODE, bdseq=0, seq=seq, timestamp=NOW)).seq]
    sent.append(host.read(encode_dbirth(LASER, seq=seq, timestamp=NOW)).seq)
    for i in range(600):
        if i % 97 == 0:
            sent.append(host.read(encode_ddeath(seq=seq, timestamp=NOW)).seq)
        elif i % 3:
            sent.append(host.read(encode_ddata(LASER[:1], seq=seq, timestamp=NOW), TYPES).seq)
        else:
            sent.append(host.read(encode_ndata(NODE[:1], seq=seq, timestamp=NOW), TYPES).seq)
    assert sent == [n % 256 for n in range(len(sent))]
    assert 255 in sent and sent.count(0) == 3


def test_a_rebirth_starts_the_sequence_again_and_keeps_the_bdseq() -> None:
    seq, bd = Seq(), BdSeq()
    bd.connect()
    encode_nbirth(NODE, bdseq=bd.current, seq=seq, timestamp=NOW)
    for _ in range(10):
        encode_ddata(LASER[:1], seq=seq, timestamp=NOW)
    again = host.read(encode_nbirth(NODE, bdseq=bd.current, seq=seq, timestamp=NOW))
    assert again.seq == 0 and next(m.value for m in again.metrics if m.name == BDSEQ) == 0
    assert host.read(encode_dbirth(LASER, seq=seq, timestamp=NOW)).seq == 1


def test_bdseq_counts_connects_from_zero_and_wraps() -> None:
    bd = BdSeq()
    with pytest.raises(ValueError, match="no CONNECT yet"):
        _ = bd.current
    assert [bd.connect() for _ in range(258)] == [n % 256 for n in range(258)]
    assert BdSeq(last=255).connect() == 0 and BdSeq(last=41).connect() == 42
    with pytest.raises(ValueError):
        BdSeq(last=256)


def test_a_refused_message_does_not_use_up_a_seq() -> None:
    seq = Seq()
    encode_nbirth([], bdseq=0, seq=seq, timestamp=NOW)
    with pytest.raises(Unencodable):
        encode_ddata([Metric("A", T("Int16"), 10**6, NOW, alias=1)], seq=seq, timestamp=NOW)
    with pytest.raises(BadBirth):
        encode_dbirth(
            [Metric("A", T("Int16"), 1, NOW), Metric("A", T("Int16"), 2, NOW)], seq=seq, timestamp=NOW
        )
    assert host.read(encode_ddeath(seq=seq, timestamp=NOW)).seq == 1


# --- every type through a birth and a data message ---------------------------------------------------


@pytest.mark.parametrize("spec", ALL_SPECS, ids=str)
@given(data=st.data())
def test_every_type_round_trips_through_births_and_data(spec: TypeSpec, data: st.DataObject) -> None:
    value = data.draw(values(spec), label="value")
    ts = data.draw(st.integers(0, 2**64 - 1), label="timestamp")
    alias = data.draw(st.integers(0, 2**64 - 1), label="alias")
    metric = Metric("Some/Path", spec, value, ts, alias=alias)
    birth = host.read(encode_dbirth([metric], seq=Seq(), timestamp=NOW)).metrics[0]
    assert (birth.name, birth.alias, birth.datatype, birth.timestamp) == (
        "Some/Path",
        alias,
        int(sparkplug_type(spec)),
        ts,
    )
    assert same(birth.value, value)
    assert birth.datatype is not None
    update = host.read(encode_ddata([metric], seq=Seq(), timestamp=NOW), {alias: birth.datatype}).metrics[0]
    assert same(update.value, value) and update.timestamp == ts


# --- refusals -------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("metrics", "fragment"),
    [
        ([Metric("A", T("Int16"), 1, NOW), Metric("A", T("Int16"), 2, NOW)], "A: the name appears twice"),
        ([Metric("A", T("Int16"), 1, NOW, alias=3), Metric("B", T("Int16"), 2, NOW, alias=3)],
         "B: alias 3 is also 'A'"),
        ([Metric("", T("Int16"), 1, NOW)], "needs a name"),
        ([Metric("A", T("Int16"), 1, NOW, historical=True)], "not historical ones"),
    ],
)  # fmt: skip
def test_births_that_would_break_the_specification_are_refused(metrics: list[Metric], fragment: str) -> None:
    with pytest.raises(BadBirth) as info:
        encode_dbirth(metrics, seq=Seq(), timestamp=NOW)
    assert fragment in str(info.value)


@pytest.mark.parametrize("name", [BDSEQ, REBIRTH])
def test_nbirth_writes_its_own_reserved_metrics(name: str) -> None:
    with pytest.raises(BadBirth, match="writes this metric of the NBIRTH itself"):
        encode_nbirth([Metric(name, T("Boolean"), True, NOW)], bdseq=0, seq=Seq(), timestamp=NOW)


@pytest.mark.parametrize(
    ("call", "fragment"),
    [
        (lambda: encode_ddata([], seq=Seq(), timestamp=NOW), "at least one metric"),
        (lambda: encode_ddeath(seq=Seq(), timestamp=-1), "uint64, got -1"),
        (lambda: encode_ddata([Metric("A", T("Int16"), 1, 2**64, alias=1)], seq=Seq(), timestamp=NOW),
         "uint64"),
        (lambda: encode_ddata([Metric("A", T("Int16"), 1, NOW, alias=-1)], seq=Seq(), timestamp=NOW),
         "alias -1 is not a uint64"),
        (lambda: encode_ddata([Metric("Feed", T("Int16"), "5", NOW, alias=1)], seq=Seq(), timestamp=NOW),
         "Feed: an Int16 needs an integer"),
        (lambda: encode_dbirth([Metric("A", T("Int16"), 1, NOW,
                                       properties={"k": Property(SparkplugType.Int8, 300)})],
                               seq=Seq(), timestamp=NOW), "property 'k': 300 does not fit an Int8"),
        (lambda: encode_dbirth([Metric("A\ud800", T("Int16"), 1, NOW)], seq=Seq(), timestamp=NOW),
         "a metric name with a lone surrogate at 1"),
        (lambda: encode_dbirth([Metric("A", T("Int16"), 1, NOW,
                                       properties={"\udc00": Property(SparkplugType.Int8, 1)})],
                               seq=Seq(), timestamp=NOW), "a property key with a lone surrogate"),
        (lambda: encode_ndeath(bdseq=256), "bdSeq is 0..255"),
        (lambda: encode_nbirth([], bdseq=-1, seq=Seq(), timestamp=NOW), "bdSeq is 0..255"),
        (lambda: encode_ddeath(seq=Seq(), timestamp=True), "uint64, got True"),
    ],
)  # fmt: skip
def test_inputs_the_wire_cannot_carry_are_refused(call: object, fragment: str) -> None:
    assert callable(call)
    with pytest.raises(Unencodable) as info:
        call()
    assert fragment in str(info.value)


def test_a_datetime_metric_before_1970() -> None:
    early = datetime(1601, 1, 1, tzinfo=UTC)  # the gateway's neutral DateTime
    seen = host.read(
        encode_dbirth([Metric("T", T("DateTime"), early, NOW, alias=1)], seq=Seq(), timestamp=NOW)
    )
    assert seen.metrics[0].value == early


def test_aliases_are_unique_across_the_node_and_stable_across_rebirths() -> None:
    aliases = Aliases()
    names = ["Axes/X/Position", "Feed/Override", "Status/State"]
    first = {
        (device, name): aliases.alias(device, name) for device in (None, "laser", "press") for name in names
    }
    assert len(set(first.values())) == len(first) == len(aliases) == 9  # node and every device together
    assert min(first.values()) == 1
    again = {
        (device, name): aliases.alias(device, name) for device in ("press", None, "laser") for name in names
    }
    assert again == first
    node = [Metric(n, T("Double"), 0.0, NOW, alias=aliases.alias(None, n)) for n in names]
    laser = [Metric(n, T("Double"), 0.0, NOW, alias=aliases.alias("laser", n)) for n in names]
    seq = Seq()
    born = host.read(encode_nbirth(node, bdseq=0, seq=seq, timestamp=NOW)).metrics
    born += host.read(encode_dbirth(laser, seq=seq, timestamp=NOW)).metrics
    bound = [m.alias for m in born if m.alias is not None]
    assert len(bound) == len(set(bound)) == 6


# --- store-and-forward -------------------------------------------------------------------------------


def test_a_stored_message_is_historical_by_name_and_takes_no_seq() -> None:
    seq = Seq()
    kept = encode_stored(
        [
            Metric("Axes/X/Position", T("Double"), 1.5, NOW - 9, alias=10),
            Metric("Feed/Override", T("UInt16"), 80, NOW - 10, alias=11),
        ],
        timestamp=NOW,
    )
    raw = Payload.FromString(kept)
    assert not raw.HasField("seq") and seq.peek == 0
    assert [(m.name, m.HasField("alias"), m.is_historical) for m in raw.metrics] == [
        ("Feed/Override", False, True),
        ("Axes/X/Position", False, True),
    ]


def test_a_released_message_goes_by_this_sessions_aliases_with_the_next_seq() -> None:
    kept = encode_stored(
        [
            Metric("Axes/X/Position", T("Double"), 1.5, NOW - 9),
            Metric("Feed/Override", T("UInt16"), 80, NOW - 10),
        ],
        timestamp=NOW - 5,
    )
    seq = Seq()
    encode_nbirth([], bdseq=3, seq=seq, timestamp=NOW)
    released = release_stored(kept, {"Axes/X/Position": 40, "Feed/Override": 41}, seq=seq)
    assert released.payload is not None and released.dropped == ()
    seen = host.read(released.payload, {40: host.DOUBLE, 41: host.UINT16})
    assert seen.seq == 1 and seen.timestamp == NOW - 5
    assert [(m.name, m.alias, m.value, m.timestamp, m.is_historical) for m in seen.metrics] == [
        (None, 41, 80, NOW - 10, True),
        (None, 40, 1.5, NOW - 9, True),
    ]
    assert seq.next() == 2


def test_stored_metrics_the_new_births_lack_are_left_out_and_named() -> None:
    kept = encode_stored(
        [Metric("Gone/Variable", T("Int32"), 1, NOW), Metric("Laser/On", T("Boolean"), True, NOW)],
        timestamp=NOW,
    )
    seq = Seq()
    released = release_stored(kept, {"Laser/On": 5}, seq=seq)
    assert released.dropped == ("Gone/Variable",)
    assert released.payload is not None
    assert [(m.alias, m.value) for m in host.read(released.payload, {5: host.BOOLEAN}).metrics] == [(5, True)]
    nothing = release_stored(
        encode_stored([Metric("Gone/Variable", T("Int32"), 1, NOW)], timestamp=NOW), {"Laser/On": 5}, seq=seq
    )
    assert nothing == Released(None, ("Gone/Variable",)) and seq.peek == 1  # no seq used up


def test_stored_bytes_that_are_no_payload_are_refused() -> None:
    with pytest.raises(MalformedPayload):
        release_stored(b"\xff", {}, seq=Seq())
    with pytest.raises(Unencodable):
        encode_stored([], timestamp=NOW)


def test_a_command_as_a_host_sends_it_reads_back_as_the_edge_node_reads_it() -> None:
    table = MetricTable([Definition("Feed/Override", T("UInt16"), 11)])
    rebirth = Metric(REBIRTH, T("Boolean"), True, NOW)
    assert decode_ncmd(encode_command([rebirth], timestamp=NOW), table).rebirth
    raw = Payload.FromString(
        encode_command([Metric("Feed/Override", T("UInt16"), 50, NOW, alias=11)], timestamp=NOW)
    )
    assert (
        not raw.HasField("seq")
        and not raw.metrics[0].HasField("name")
        and not raw.metrics[0].HasField("datatype")
    )
    [write] = decode_dcmd(raw.SerializeToString(), table).writes
    assert (write.metric.name, write.value) == ("Feed/Override", 50)
    with pytest.raises(Unencodable):
        encode_command([], timestamp=NOW)

"""Reading an agent's answers (responses.py), multipart streams, condition lists, units and buffer restore."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.codecs.mtconnect.buffer import ObservationBuffer
from gateway.codecs.mtconnect.conditions import ActiveCondition, format_condition_text, parse_condition_text
from gateway.codecs.mtconnect.documents import DocumentInfo, devices_xml, error_xml, streams_xml
from gateway.codecs.mtconnect.errors import OutOfRange
from gateway.codecs.mtconnect.model import Category, walk
from gateway.codecs.mtconnect.multipart import MultipartReader, boundary_of, encode_part
from gateway.codecs.mtconnect.responses import (
    AgentErrors,
    ResponseError,
    document_kind,
    parse_devices,
    parse_error,
    parse_streams,
)
from gateway.codecs.mtconnect.units import factor, native_units, standard_units

from .machines import shop

T0 = "2024-05-01T12:00:00.000000Z"
INFO = DocumentInfo("test", T0, T0)


def test_a_probe_reads_back_as_the_model_it_was_rendered_from() -> None:
    catalog = shop(2)
    parsed = parse_devices(devices_xml(catalog, INFO, instance_id=7, buffer_size=64, asset_buffer_size=4,
                                       asset_count=0))  # fmt: skip
    assert parsed.header.instance_id == 7
    assert [d.uuid for d in parsed.devices] == [d.uuid for d in catalog.devices]
    original = {i.id: i for n in walk(catalog.devices[0]) for i in n.data_items}
    read = {i.id: i for n in walk(parsed.devices[0]) for i in n.data_items}
    assert read.keys() == original.keys()
    for item_id, item in original.items():
        got = read[item_id]
        assert (got.category, got.type, got.name, got.sub_type, got.units, got.native_units) == (
            item.category, item.type, item.name, item.sub_type, item.units, item.native_units,
        )  # fmt: skip


def test_streams_read_back_with_sequences_conditions_and_header() -> None:
    catalog = shop(1)
    buffer = ObservationBuffer(catalog, instance_id=3, size=32)
    buffer.add_unavailable(catalog.items, T0)
    buffer.add_value("m1_Xpos", T0, 12.5)
    buffer.add_condition("m1_system", T0, "FAULT", native_code="E42", native_severity="3", text="Hot")
    entries, window = buffer.current()
    doc = parse_streams(streams_xml(catalog, entries, window, INFO))
    assert doc.header.instance_id == 3 and doc.header.next_sequence == buffer.next_sequence
    by_id = {o.data_item_id: o for o in doc.observations}
    assert by_id["m1_Xpos"].value == "12.5" and by_id["m1_Xpos"].category is Category.SAMPLE
    fault = by_id["m1_system"]
    assert (fault.level, fault.native_code, fault.native_severity, fault.value) == (
        "FAULT",
        "E42",
        "3",
        "Hot",
    )
    assert by_id["m1_Ypos"].unavailable
    assert [o.sequence for o in doc.observations] == sorted(o.sequence for o in doc.observations)


def test_error_documents_are_raised_with_their_codes() -> None:
    text = error_xml(
        [OutOfRange("from", 1, 5, 9, "'from' must be in [5, 9]")], INFO, instance_id=1, buffer_size=8
    )
    assert document_kind(text) == "Error"
    assert parse_error(text)[0].code == "OUT_OF_RANGE"
    with pytest.raises(AgentErrors) as caught:
        parse_streams(text)
    assert caught.value.codes == {"OUT_OF_RANGE"}


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("<MTConnectStreams><Streams/></MTConnectStreams>", "no Header"),
        ("<nope/>", "expected MTConnectStreams"),
        ("<MTConnectStreams><Header", "not well-formed"),
        ('<!DOCTYPE x [<!ENTITY a "b">]><MTConnectStreams/>', "DOCTYPE"),
        ('<MTConnectStreams><Header instanceId="x"/></MTConnectStreams>', "not an integer"),
    ],
)
def test_junk_answers_are_refused_with_a_reason(text: str, fragment: str) -> None:
    with pytest.raises(ResponseError, match=fragment):
        parse_streams(text)


def test_a_multipart_stream_splits_into_its_parts_at_every_offset() -> None:
    bodies = [b"<a/>", b"", b"x" * 300, "ünï".encode()]
    wire = b"".join(encode_part("B0UND", body) for body in bodies)
    assert boundary_of("multipart/x-mixed-replace;boundary=B0UND") == "B0UND"
    for cut in range(len(wire) + 1):
        reader = MultipartReader("B0UND")
        parts = reader.feed(wire[:cut]) + reader.feed(wire[cut:])
        assert parts == bodies and reader.failed is None


@pytest.mark.parametrize(
    ("wire", "fragment"),
    [
        (b"garbage\r\n\r\n", "expected the boundary"),
        (b"--B\r\nContent-type: text/xml\r\n\r\n<a/>", "without a Content-length"),
        (b"--B\r\nContent-length: 99999999999\r\n\r\n", "more than"),
        (b"x" * 70_000, "no part header"),
    ],
)
def test_a_broken_stream_fails_with_a_reason(wire: bytes, fragment: str) -> None:
    reader = MultipartReader("B", max_part=1 << 20)
    assert reader.feed(wire) == []
    assert reader.failed is not None and fragment in reader.failed


conditions = st.builds(
    ActiveCondition,
    level=st.sampled_from(["WARNING", "FAULT"]),
    native_code=st.none()
    | st.text(
        st.characters(blacklist_characters=':\r\n|\\"', blacklist_categories=("Cs", "Zs", "Cc")),
        min_size=1,
        max_size=8,
    ),
    native_severity=st.none() | st.sampled_from(["1", "2", "3"]),
    qualifier=st.none() | st.sampled_from(["HIGH", "LOW"]),
    text=st.text(st.characters(blacklist_categories=("Cs", "Cc")), max_size=30).map(str.strip),
    condition_id=st.none(),
)


@given(conditions)
def test_a_condition_survives_its_text_form(condition: ActiveCondition) -> None:
    back = parse_condition_text(format_condition_text(condition))
    assert back.level == condition.level and back.native_code == condition.native_code
    assert back.native_severity == condition.native_severity and back.qualifier == condition.qualifier
    assert back.text == condition.text
    assert back.key == condition.key


def test_condition_ids_and_bad_entries() -> None:
    c = parse_condition_text('FAULT|E42:c1|2|HIGH|"Laser overheated \\| really"')
    assert (c.native_code, c.condition_id, c.text) == ("E42", "c1", "Laser overheated | really")
    loose = parse_condition_text("WARNING|W7||LOW|an unquoted | pipe")  # extra fields stay in the text
    assert (loose.level, loose.qualifier, loose.text) == ("WARNING", "LOW", "an unquoted|pipe")
    with pytest.raises(ValueError, match="WARNING or FAULT"):
        parse_condition_text("NORMAL||||")


def test_units_name_and_convert_what_controllers_use() -> None:
    assert native_units("mm/min") == "MILLIMETER/MINUTE" and native_units("W") == "WATT"
    assert native_units("furlongs") is None and native_units("MILLIMETER") == "MILLIMETER"
    assert standard_units("MILLIMETER/MINUTE") == "MILLIMETER/SECOND"
    assert factor("MILLIMETER/MINUTE", "MILLIMETER/SECOND") == pytest.approx((1 / 60, 0.0))
    scale, offset = factor("FAHRENHEIT", "CELSIUS")
    assert 212 * scale + offset == pytest.approx(100.0)
    assert factor("MILLIMETER", "MILLIMETER") == (1.0, 0.0)


def test_a_restored_buffer_keeps_its_sequences_and_answers_from_them() -> None:
    catalog = shop(1)
    first = ObservationBuffer(catalog, instance_id=5, size=8)
    for n in range(20):
        first.add_value("m1_Xpos", T0, n)
    kept = list(first.entries_between(first.first_sequence, first.next_sequence))
    second = ObservationBuffer(catalog, instance_id=5, size=8)
    second.restore(kept)
    assert (second.first_sequence, second.next_sequence) == (first.first_sequence, first.next_sequence)
    assert [e.value for e in second.sample(from_=15, count=3).entries] == ["14", "15", "16"]
    with pytest.raises(OutOfRange):
        second.sample(from_=12)
    empty = ObservationBuffer(catalog, instance_id=5, size=8)
    empty.resume_at(21)
    assert (empty.first_sequence, empty.next_sequence) == (21, 21)
    assert empty.add_value("m1_Xpos", T0, 1) is not None and empty.last_sequence == 21


def test_restore_refuses_a_gap() -> None:
    catalog = shop(1)
    first = ObservationBuffer(catalog, instance_id=5, size=8)
    for n in range(6):
        first.add_value("m1_Xpos", T0, n)
    kept = list(first.entries_between(1, 7))
    del kept[2]
    with pytest.raises(ValueError, match="gap"):
        ObservationBuffer(catalog, instance_id=5, size=8).restore(kept)

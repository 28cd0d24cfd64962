"""Samples to frames: each type decodes back by the codec, frames split at max_cbdata, bad values stay out."""

from __future__ import annotations

import logging
from datetime import UTC, datetime

import pytest

from gateway.codecs.copydata import FrameDecoder, Layout, decode_lpdata
from gateway.model.sample import Sample, utcnow
from gateway.model.tree import VariableTree
from gateway.sinks.copydata.emitter import target_layout, target_nodes
from gateway.sinks.copydata.encoder import TargetEncoder
from tests.unit.sinks.copydata.helpers import ingest, mapping

VALUES = {
    "Axes/X/Position": 1234.5,
    "Axes/Y/Position": -0.25,
    "Program/Block": 42,
    "Laser/On": True,
    "Program/Name": "Teil-Ø3.nc",
    "Alarms2/Texts": ["Gas low", "Düse"],
    "Program/Start": datetime(2024, 1, 1, tzinfo=UTC),
    "Laser/Table": [0.5, 100.0],
    "Feed/Override": 80,
}


def encoder_for(layout: Layout | None = None, **target: object):  # type: ignore[no-untyped-def]
    mp = mapping({"name": "nest", "transport": "tcp-server", **target})
    m = VariableTree([mp.definition()]).machines["m1"]
    t = mp.copydata.targets[0]  # type: ignore[union-attr]
    return m, TargetEncoder("m1/nest", target_nodes(m, mp, t), layout or target_layout(t))


def decoded(encoder: TargetEncoder, frames: list[tuple[int, bytes]]) -> dict[str, object]:
    out: dict[str, object] = {}
    for dwdata, lpdata in frames:
        frame = decode_lpdata(dwdata, lpdata, encoder.layout)
        for reading in encoder.table.decode(frame, encoder.layout):
            out[reading.variable.name] = reading.value
    return out


@pytest.mark.parametrize(
    ("widths", "encoding"), [((2, 2), "utf-8"), ((1, 4), "utf-16-le"), ((4, 1), "utf-8")]
)
def test_a_snapshot_decodes_to_the_tree_values(widths: tuple[int, int], encoding: str) -> None:
    m, enc = encoder_for(id_width=widths[0], len_width=widths[1], encoding=encoding)
    for path, value in VALUES.items():
        ingest(m, path, value)
    frames = enc.snapshot()
    assert [dwdata for dwdata, _ in frames] == [2]
    assert decoded(enc, frames) == VALUES


def test_single_frames_are_dwdata_1_with_one_item() -> None:
    m, enc = encoder_for()
    node = ingest(m, "Program/Block", 7)
    frame = enc.single(node, node.sample)
    assert frame is not None and frame[0] == 1
    assert frame[1] == bytes.fromhex("0500 0400 07000000")


def test_fixed_width_variables_get_a_prebuilt_header() -> None:
    m, enc = encoder_for()
    assert enc.encoders[m.nodes["Axes/X/Position"]].header == bytes.fromhex("0100 0800")
    assert enc.encoders[m.nodes["Program/Name"]].header is None  # its length varies


def test_bad_values_are_not_in_snapshots() -> None:
    m, enc = encoder_for()
    ingest(m, "Axes/X/Position", 1.0)
    ingest(m, "Program/Block", 3)
    ingest(m, "Program/Block", 3, status="BadNotConnected")
    assert decoded(enc, enc.snapshot()) == {"Axes/X/Position": 1.0}


def test_a_batch_over_max_cbdata_is_split_into_several_frames() -> None:
    m, enc = encoder_for(max_cbdata=40)
    changes = []
    for path in ["Axes/X/Position", "Axes/Y/Position", "Program/Block", "Laser/On", "Feed/Override"]:
        node = ingest(m, path, VALUES[path])
        changes.append((node, node.sample))
    frames = enc.batch(changes)
    assert len(frames) == 2 and all(dw == 2 and len(lp) <= 40 for dw, lp in frames)
    assert decoded(enc, frames) == {
        p: VALUES[p]
        for p in ("Axes/X/Position", "Axes/Y/Position", "Program/Block", "Laser/On", "Feed/Override")
    }


def test_a_value_that_cannot_be_encoded_is_left_out_and_logged_once(caplog: pytest.LogCaptureFixture) -> None:
    m, enc = encoder_for(encoding="cp1252")
    name = m.nodes["Program/Name"]
    block = ingest(m, "Program/Block", 9)
    caplog.set_level(logging.WARNING)
    for _ in range(3):
        frames = enc.batch([(name, Sample("部品.nc", utcnow())), (block, block.sample)])
        assert decoded(enc, frames) == {"Program/Block": 9}
    warnings = [r for r in caplog.records if "Program/Name is left out" in r.getMessage()]
    assert len(warnings) == 1 and "cp1252" in warnings[0].getMessage()
    assert enc.skipped == 3
    assert enc.single(name, Sample("part.nc", utcnow())) is not None  # sent again once it fits
    assert name not in enc.failing


def test_a_string_too_long_for_a_one_byte_length_is_left_out() -> None:
    m, enc = encoder_for(len_width=1)
    name = m.nodes["Program/Name"]
    assert enc.single(name, Sample("x" * 256, utcnow())) is None
    assert enc.single(name, Sample("x" * 255, utcnow())) is not None


def test_frames_travel_as_tcp_and_decode_in_any_chunking() -> None:
    from gateway.sinks.copydata.tcp import pack

    m, enc = encoder_for()
    for path, value in VALUES.items():
        ingest(m, path, value)
    wire = pack(enc.snapshot() + enc.snapshot())
    decoder = FrameDecoder(enc.layout)
    frames = [f for i in range(0, len(wire), 7) for f in decoder.feed(wire[i : i + 7])]
    assert len(frames) == 2
    assert {r.variable.name: r.value for r in enc.table.decode(frames[1], enc.layout)} == VALUES


def test_connected_flag_is_sent_under_its_own_id() -> None:
    m, enc = encoder_for(connected_id=100)
    m.status.connected()
    ingest(m, "Program/Block", 1)
    assert decoded(enc, enc.snapshot()) == {"Status/Connected": True, "Program/Block": 1}


def test_a_target_may_choose_a_subset() -> None:
    _m, enc = encoder_for(variables=["Program/Block", "Laser/On"])
    assert sorted(v.name for v in enc.table) == ["Laser/On", "Program/Block"]

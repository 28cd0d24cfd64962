"""The incremental TCP decoder: any chunking, bounded memory, and a final failed state."""

from __future__ import annotations

import contextlib
import itertools
from datetime import UTC, datetime

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.codecs.copydata import (
    BadBoolean,
    CopydataError,
    DecoderFailed,
    Frame,
    FrameDecoder,
    FrameTooLarge,
    Item,
    ItemCountMismatch,
    Layout,
    LengthOverrun,
    TruncatedFrame,
    UnknownDwData,
    VariableTable,
    pack_tcp,
)
from gateway.codecs.copydata.stream import HEADER_SIZE

LAYOUT = Layout()
TABLE = VariableTable.from_ids(
    {
        1: ("Axes/X/Position", "Double"),
        5: ("Program/Block", "UInt32"),
        7: ("Laser/On", "Boolean"),
        9: ("Program/Name", "String"),
        11: ("ActiveAlarms/Texts", "String[]"),
        12: ("Clock", "DateTime"),
    }
)
FRAMES = [
    TABLE.encode({1: 1234.5}, LAYOUT),
    TABLE.encode({1: -0.25, 5: 42, 7: True, 9: "PART-01.nc"}, LAYOUT),
    TABLE.encode(
        {11: ["Gas pressure low", "Düse verschmutzt"], 12: datetime(2024, 1, 1, tzinfo=UTC)}, LAYOUT
    ),
    TABLE.encode({7: False}, LAYOUT),
    Frame.multi([Item(5, b"\x00\x00\x00\x00")]),
]
STREAM = b"".join(pack_tcp(f, LAYOUT) for f in FRAMES)


def feed_chunks(chunks: list[bytes], layout: Layout = LAYOUT) -> list[Frame]:
    decoder = FrameDecoder(layout)
    frames: list[Frame] = []
    for chunk in chunks:
        frames += decoder.feed(chunk)
        assert decoder.buffered <= HEADER_SIZE + layout.max_cbdata
    decoder.feed_eof()
    return frames


def test_whole_stream_in_one_feed() -> None:
    assert feed_chunks([STREAM]) == FRAMES


def test_split_at_every_offset() -> None:
    for cut in range(len(STREAM) + 1):
        assert feed_chunks([STREAM[:cut], STREAM[cut:]]) == FRAMES, f"split at {cut}"


def test_byte_by_byte() -> None:
    assert feed_chunks([STREAM[i : i + 1] for i in range(len(STREAM))]) == FRAMES


def test_split_at_every_pair_of_offsets_over_two_frames() -> None:
    two = pack_tcp(FRAMES[0], LAYOUT) + pack_tcp(FRAMES[3], LAYOUT)
    for a in range(len(two) + 1):
        for b in range(a, len(two) + 1):
            assert feed_chunks([two[:a], two[a:b], two[b:]]) == [FRAMES[0], FRAMES[3]]


@given(st.lists(st.integers(0, len(STREAM)), max_size=12))
def test_random_chunkings(cuts: list[int]) -> None:
    bounds = [0, *sorted(cuts), len(STREAM)]
    chunks = [STREAM[a:b] for a, b in itertools.pairwise(bounds)]
    assert feed_chunks(chunks) == FRAMES


def test_frames_come_out_as_soon_as_they_are_complete() -> None:
    first = pack_tcp(FRAMES[0], LAYOUT)
    decoder = FrameDecoder(LAYOUT)
    assert decoder.feed(first[:-1]) == []
    assert decoder.buffered == len(first) - 1 and decoder.position == 0
    assert decoder.feed(first[-1:] + STREAM[len(first) : len(first) + 3]) == [FRAMES[0]]
    assert decoder.buffered == 3 and decoder.position == len(first)


# --- errors ----------------------------------------------------------------------------------


def test_unknown_dwdata_is_refused_as_soon_as_its_four_bytes_arrive() -> None:
    decoder = FrameDecoder(LAYOUT)
    assert decoder.feed(b"\x03\x00\x00") == []
    with pytest.raises(UnknownDwData) as info:
        decoder.feed(b"\x00")
    assert info.value.offset == 0 and decoder.buffered == 0


def test_cbdata_over_the_maximum_is_refused_from_the_header_alone() -> None:
    layout = Layout(max_cbdata=64)
    good = pack_tcp(Frame.single(Item(1, b"x")), layout)
    decoder = FrameDecoder(layout)
    with pytest.raises(FrameTooLarge, match="cbData 65 is over max_cbdata 64") as info:
        decoder.feed(good + b"\x02\x00\x00\x00\x41\x00\x00\x00")  # no lpData sent at all
    assert info.value.offset == len(good) + 4
    assert decoder.buffered == 0 and decoder.failed is info.value
    assert info.value.frames == (Frame.single(Item(1, b"x")),)


def test_cbdata_at_the_maximum_is_accepted() -> None:
    layout = Layout(max_cbdata=64)
    frame = Frame.single(Item(1, bytes(60)))
    assert feed_chunks([pack_tcp(frame, layout)], layout) == [frame]


def test_lpdata_errors_carry_the_stream_offset() -> None:
    good = pack_tcp(FRAMES[0], LAYOUT)
    bad = bytes.fromhex("02000000 05000000 0100 0900 01")  # length 9, only 1 byte left
    decoder = FrameDecoder(LAYOUT)
    with pytest.raises(LengthOverrun, match=f"^frame at byte {len(good)}: item 0") as info:
        decoder.feed(good + bad)
    assert info.value.offset == len(good) + 8 + 2
    assert info.value.frames == (FRAMES[0],)


def test_dwdata_1_with_two_items_in_the_stream() -> None:
    bad = bytes.fromhex("01000000 0a000000 0100 0100 07 0200 0100 08")
    with pytest.raises(ItemCountMismatch) as info:
        FrameDecoder(LAYOUT).feed(bad)
    assert info.value.offset == 8 + 5


def test_end_of_stream_inside_a_frame() -> None:
    decoder = FrameDecoder(LAYOUT)
    first = pack_tcp(FRAMES[0], LAYOUT)
    decoder.feed(first + STREAM[len(first) : len(first) + 10])
    with pytest.raises(TruncatedFrame, match="stream ended 10 bytes into a frame") as info:
        decoder.feed_eof()
    assert info.value.offset == len(first)


def test_end_of_stream_inside_a_header() -> None:
    decoder = FrameDecoder(LAYOUT)
    decoder.feed(b"\x01\x00\x00\x00\x0c")
    with pytest.raises(TruncatedFrame, match="need at least 8 bytes"):
        decoder.feed_eof()


def test_a_failed_decoder_refuses_more_input() -> None:
    decoder = FrameDecoder(LAYOUT)
    with pytest.raises(UnknownDwData) as first:
        decoder.feed(b"\x00" * 8)
    with pytest.raises(DecoderFailed, match="cannot resynchronise") as again:
        decoder.feed(STREAM)
    assert again.value.__cause__ is first.value
    with pytest.raises(DecoderFailed):
        decoder.feed_eof()
    assert decoder.failed is first.value


def test_feed_after_end_of_stream_is_refused() -> None:
    decoder = FrameDecoder(LAYOUT)
    decoder.feed(STREAM)
    decoder.feed_eof()
    with pytest.raises(DecoderFailed, match="already told the stream ended"):
        decoder.feed(STREAM)


def test_the_decoder_checks_framing_not_meaning() -> None:
    """A Boolean byte 5 frames fine; the table refuses it, and the stream stays usable."""
    frame = Frame.single(Item(7, b"\x05"))
    decoder = FrameDecoder(LAYOUT)
    assert decoder.feed(pack_tcp(frame, LAYOUT)) == [frame]
    with pytest.raises(BadBoolean):
        TABLE.decode(frame, LAYOUT)
    assert decoder.feed(STREAM) == FRAMES


# --- fuzzing ---------------------------------------------------------------------------------


def _check_garbage(chunks: list[bytes], layout: Layout) -> None:
    decoder = FrameDecoder(layout)
    fed = 0
    try:
        for chunk in chunks:
            fed += len(chunk)
            frames = decoder.feed(chunk)
            assert decoder.buffered <= HEADER_SIZE + layout.max_cbdata
            assert decoder.position + decoder.buffered == fed
            for frame in frames:
                assert frame.dwdata in (1, 2) and frame.items
        decoder.feed_eof()
    except CopydataError as exc:
        assert exc.offset is not None and 0 <= exc.offset <= fed
        assert decoder.failed is exc and decoder.buffered == 0


@settings(max_examples=300)
@given(
    chunks=st.lists(st.binary(max_size=80), max_size=10),
    max_cbdata=st.sampled_from([1, 16, 64, 1 << 20]),
    widths=st.tuples(st.sampled_from([1, 2, 4]), st.sampled_from([1, 2, 4])),
)
def test_arbitrary_bytes_only_raise_copydata_errors(
    chunks: list[bytes], max_cbdata: int, widths: tuple[int, int]
) -> None:
    _check_garbage(chunks, Layout(id_width=widths[0], len_width=widths[1], max_cbdata=max_cbdata))


@st.composite
def _mutated_streams(draw: st.DrawFn) -> list[bytes]:
    """A valid stream with a few bytes changed, inserted or cut: garbage that gets past the header."""
    data = bytearray(STREAM)
    for _ in range(draw(st.integers(1, 4))):
        pos = draw(st.integers(0, len(data) - 1))
        action = draw(st.sampled_from(["set", "insert", "delete"]))
        if action == "set":
            data[pos] = draw(st.integers(0, 255))
        elif action == "insert":
            data[pos:pos] = draw(st.binary(min_size=1, max_size=4))
        else:
            del data[pos : pos + draw(st.integers(1, 4))]
    cuts = sorted(draw(st.lists(st.integers(0, len(data)), max_size=6)))
    bounds = [0, *cuts, len(data)]
    return [bytes(data[a:b]) for a, b in itertools.pairwise(bounds)]


@settings(max_examples=300)
@given(chunks=_mutated_streams(), max_cbdata=st.sampled_from([40, 1 << 20]))
def test_mutated_streams_only_raise_copydata_errors(chunks: list[bytes], max_cbdata: int) -> None:
    layout = Layout(max_cbdata=max_cbdata)
    _check_garbage(chunks, layout)
    # What framed correctly must also decode or be refused with a CopydataError by the table.
    decoder = FrameDecoder(layout)
    try:
        frames = [f for c in chunks for f in decoder.feed(c)]
    except CopydataError:
        return
    for frame in frames:
        with contextlib.suppress(CopydataError):
            TABLE.decode(frame, layout)

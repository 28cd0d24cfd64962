"""The hex examples in docs/copydata.md decode to the values the text claims, and re-encode to the same bytes.

Each example is a fenced block right after a `<!-- copydata-example: NAME -->` marker, with lines
`offset | hex bytes | meaning`. The offsets are checked too, so the annotations cannot drift.
"""

from __future__ import annotations

import re
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest

from gateway.codecs.copydata import (
    FrameDecoder,
    Layout,
    VariableTable,
    decode_lpdata,
    encode_lpdata,
    pack_tcp,
)

DOC = Path(__file__).resolve().parents[3] / "docs" / "copydata.md"
BLOCK = re.compile(r"<!-- copydata-example: (?P<name>[\w-]+) -->\s*```\w*\n(?P<body>.*?)```", re.DOTALL)

LAYOUT = Layout()  # the examples use the defaults: 2-byte ids and lengths, utf-8
TABLE = VariableTable.from_ids(
    {
        1: ("Axes/X/Position", "Double"),
        5: ("Program/Block", "UInt32"),
        7: ("Laser/On", "Boolean"),
        9: ("Program/Name", "String"),
        11: ("ActiveAlarms/Texts", "String[]"),
        12: ("Program/StartTime", "DateTime"),
        13: ("Laser/PowerTable", "Double[]"),
    }
)
WORKED_EXAMPLE = [(1, 1234.5), (5, 42), (7, True), (9, "Teil-Ø3.nc")]
TCP_EXAMPLES: dict[str, list[tuple[int, Any]]] = {
    "tcp": WORKED_EXAMPLE,
    "filetime": [(12, datetime(2024, 1, 1, tzinfo=UTC))],
    "double-array": [(13, [0.5, 100.0])],
    "string-array": [(11, ["Gas low", "Düse"])],
}


def examples() -> dict[str, bytes]:
    found: dict[str, bytes] = {}
    for match in BLOCK.finditer(DOC.read_text(encoding="utf-8")):
        data = bytearray()
        for line in match["body"].splitlines():
            columns = line.split("|")
            if len(columns) < 2 or not columns[0].strip().isdigit():
                continue  # the heading and the rule under it
            offset = int(columns[0])
            assert offset == len(data), f"{match['name']}: line {line!r} says offset {offset}, is {len(data)}"
            data += bytes.fromhex(columns[1])
        found[match["name"]] = bytes(data)
    return found


def test_the_doc_has_every_example() -> None:
    assert set(examples()) == {*TCP_EXAMPLES, "lpdata"}


@pytest.mark.parametrize("name", sorted(TCP_EXAMPLES))
def test_tcp_example_decodes_to_the_documented_values(name: str) -> None:
    wire = examples()[name]
    decoder = FrameDecoder(LAYOUT)
    [frame] = decoder.feed(wire)
    decoder.feed_eof()
    assert [(r.variable.id, r.value) for r in TABLE.decode(frame, LAYOUT)] == TCP_EXAMPLES[name]
    # And the other way: encoding the documented values gives the documented bytes.
    assert pack_tcp(TABLE.encode(TCP_EXAMPLES[name], LAYOUT), LAYOUT) == wire


def test_lpdata_example_is_the_tcp_example_without_its_header() -> None:
    found = examples()
    lpdata, wire = found["lpdata"], found["tcp"]
    assert len(lpdata) == 40 and wire[8:] == lpdata
    frame = decode_lpdata(2, lpdata, LAYOUT)
    assert [(r.variable.id, r.value) for r in TABLE.decode(frame, LAYOUT)] == WORKED_EXAMPLE
    assert encode_lpdata(TABLE.encode(WORKED_EXAMPLE, LAYOUT), LAYOUT) == lpdata


def test_other_widths_sentence_matches_the_codec() -> None:
    text = DOC.read_text(encoding="utf-8")
    claimed = re.search(r"the first item becomes `([0-9a-f |]+)`", text)
    assert claimed is not None
    layout = Layout(id_width=1, len_width=4)
    item = TABLE.encode({1: 1234.5}, layout).items[0]
    assert encode_lpdata(TABLE.encode({1: 1234.5}, layout), layout) == bytes.fromhex(
        claimed[1].replace("|", "")
    )
    assert item.data == bytes.fromhex("0000000000 4a9340")

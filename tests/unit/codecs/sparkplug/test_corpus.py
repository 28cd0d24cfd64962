"""Every payload in tests/corpus/sparkplug is refused with its reason, and no bytes at all crash the
command decoder: arbitrary bytes, and good commands cut or damaged at every offset."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.codecs.sparkplug import (
    Command,
    Definition,
    MetricTable,
    SparkplugError,
    decode_dcmd,
    decode_ncmd,
)
from gateway.model.types import TypeSpec
from tests.unit.codecs.sparkplug import host

CORPUS = Path(__file__).resolve().parents[3] / "corpus" / "sparkplug" / "commands.yaml"
T = TypeSpec.parse

# The births the corpus's header names.
DEVICE = MetricTable([
    Definition("Axes/X/Position", T("Double"), 10),
    Definition("Feed/Override", T("UInt16"), 11),
    Definition("Laser/On", T("Boolean"), 12),
    Definition("Program/Name", T("String"), 13),
    Definition("ActiveAlarms/Codes", T("Int32[]"), 14),
    Definition("ActiveAlarms/Acked", T("Boolean[]"), 15),
    Definition("ActiveAlarms/Texts", T("String[]"), 16),
    Definition("Program/Started", T("DateTime"), 17),
])  # fmt: skip
NODE = MetricTable([Definition("Gateway/Version", T("String"), 1)])


def load() -> list[dict[str, Any]]:
    cases = yaml.safe_load(CORPUS.read_text(encoding="utf-8"))
    assert isinstance(cases, list)
    return cases


def payload_of(case: dict[str, Any]) -> bytes:
    if "parts" in case:
        return b"".join(bytes.fromhex(part["hex"]) * part.get("times", 1) for part in case["parts"])
    return bytes.fromhex(str(case["hex"]))


def decode(message: str, data: bytes) -> Command:
    if message == "NCMD":
        return decode_ncmd(data, NODE)
    assert message == "DCMD", message
    return decode_dcmd(data, DEVICE)


CASES = load()


def test_the_corpus_covers_every_kind_of_refusal() -> None:
    assert len(CASES) >= 40
    assert len({c["name"] for c in CASES}) == len(CASES), "case names are unique"
    kinds = {c["expect"]["kind"] for c in CASES}
    assert kinds == {
        "malformed_protobuf", "bad_command", "unknown_metric", "unknown_alias", "wrong_datatype", "bad_value"
    }  # fmt: skip


@pytest.mark.parametrize("case", CASES, ids=[c["name"] for c in CASES])
def test_every_corpus_entry_is_refused_with_its_reason(case: dict[str, Any]) -> None:
    expect = case["expect"]
    try:
        command = decode(case["message"], payload_of(case))
    except SparkplugError as exc:
        refusal: SparkplugError = exc
    else:
        assert command.writes == () and command.rebirth is False, command
        assert len(command.refusals) == 1, command.refusals
        refusal = command.refusals[0]
    assert refusal.kind == expect["kind"], f"{refusal.kind}: {refusal}"
    assert expect["error"] in str(refusal), str(refusal)


GOOD = [
    host.command(
        host.write(50, host.UINT16, alias=11), host.write([True, False] * 5, host.BOOLEAN_ARRAY, alias=15)
    ),
    host.command(
        host.write(["a", "bé"], host.STRING_ARRAY, alias=16), host.write("demo.nc", host.STRING, alias=13)
    ),
    host.command(
        host.write(True, host.BOOLEAN, name="Node Control/Rebirth"), host.write("x", host.STRING, alias=1)
    ),
]


def never_crashes(data: bytes) -> None:
    for message in ("NCMD", "DCMD"):
        try:
            command = decode(message, data)
        except SparkplugError as exc:
            assert str(exc)  # a reason, never an empty message
            continue
        assert isinstance(command, Command)
        assert all(str(r) for r in command.refusals)


@pytest.mark.parametrize("good", GOOD, ids=range(len(GOOD)))
def test_a_good_command_cut_at_every_offset(good: bytes) -> None:
    for end in range(len(good)):
        never_crashes(good[:end])


@pytest.mark.parametrize("good", GOOD, ids=range(len(GOOD)))
def test_a_good_command_with_any_byte_damaged(good: bytes) -> None:
    for offset in range(len(good)):
        for value in (0x00, 0x7F, 0x80, 0xFF, good[offset] ^ 0x01):
            never_crashes(good[:offset] + bytes([value]) + good[offset + 1 :])


@settings(max_examples=300)
@given(st.binary(max_size=300))
def test_arbitrary_bytes(data: bytes) -> None:
    never_crashes(data)


@settings(max_examples=300)
@given(st.lists(st.sampled_from(GOOD), min_size=1, max_size=3), st.binary(max_size=20), st.integers(0, 400))
def test_spliced_commands(pieces: list[bytes], junk: bytes, at: int) -> None:
    whole = b"".join(pieces)
    at = min(at, len(whole))
    never_crashes(whole[:at] + junk + whole[at:])

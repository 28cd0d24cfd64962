"""ProgramCheck, validation fed in pieces, gives the whole-file verdict wherever the pieces split.

The inbox feeds an upload's blocks as they arrive; whatever the block sizes,
the verdict must be the one `validate_program` gives for the whole file:
rejections, warnings, estimate to the bit, name. `_HEAD` (the bytes held back
for the binary check, 64 KB) is lowered here so that small programs exercise
reading mid-stream too.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bench.gcode_gen import laser_program
from gateway.config.validation import ValidationRules
from gateway.jobs.validation import pipeline as validation
from gateway.jobs.validation.pipeline import ProgramCheck, Verdict, validate_program
from gateway.jobs.validation.text_checks import SAMPLE
from tests.unit.jobs.validation.test_fast_read import program
from tests.unit.jobs.validation.test_validation import CASES, header

GENERIC = ValidationRules.for_dialect("generic")
LASER = ValidationRules.for_dialect("laser-sim")


@contextmanager
def held_back(size: int) -> Iterator[None]:
    saved = validation._HEAD
    validation._HEAD = size
    try:
        yield
    finally:
        validation._HEAD = saved


def pieces(data: bytes, cuts: list[int], name: str, rules: ValidationRules) -> Verdict:
    check = ProgramCheck(rules)
    start = 0
    for cut in sorted(cuts):
        check.feed(data[start:cut])
        start = cut
    check.feed(data[start:])
    return check.finish(name)


def whole(data: bytes, name: str, rules: ValidationRules) -> Verdict:
    return dataclasses.replace(validate_program(data, name, rules), program=b"")


@pytest.mark.parametrize("path", CASES, ids=lambda p: p.name)
def test_every_corpus_file_split_at_every_offset_reads_the_same(path: Path) -> None:
    _, rules, name = header(path)
    chosen = ValidationRules.model_validate(rules)
    data = path.read_bytes()
    expected = whole(data, name, chosen)
    for head in (0, 7, SAMPLE):
        with held_back(head):
            for offset in range(len(data) + 1):
                assert pieces(data, [offset], name, chosen) == expected, (head, offset)


@settings(max_examples=500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(program(), st.lists(st.integers(0, 2000), max_size=12), st.sampled_from([0, 1, 16, SAMPLE]))
def test_generated_programs_in_any_pieces_read_the_same(
    case: tuple[bytes, ValidationRules], cuts: list[int], head: int
) -> None:
    data, rules = case
    expected = whole(data, "job.nc", rules)
    with held_back(head):
        assert pieces(data, [min(c, len(data)) for c in cuts], "job.nc", rules) == expected


@pytest.mark.parametrize("block", [1000, 4096, 65536, 100_003])
def test_a_large_program_in_upload_sized_blocks_reads_the_same(block: int) -> None:
    data = laser_program(300_000, seed=11, number=21)
    expected = whole(data, "O21.nc", LASER)
    assert expected.accepted and expected.estimate is not None and expected.estimate.blocks > 5000
    assert pieces(data, list(range(block, len(data), block)), "O21.nc", LASER) == expected


def test_the_file_name_is_judged_at_the_end() -> None:
    rules = ValidationRules.for_dialect("laser-sim", program_name="must-match")
    data = laser_program(100_000, seed=12, number=22)
    check = ProgramCheck(rules)
    check.feed(data)
    verdict = check.finish("O23.nc")
    assert not verdict.accepted and {r.rule for r in verdict.rejections} == {"program-name"}
    assert verdict == whole(data, "O23.nc", rules)


@pytest.mark.parametrize(
    "data",
    [
        laser_program(100_000, seed=13, number=5).replace(b"G1 X", b"G1\x00X", 1),  # a NUL after the head
        laser_program(100_000, seed=13, number=5)[:-200] + b"\x00" * 3,
        b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 400,
        "G1 X1\nM30\n".encode("utf-16-le") * 5000,
        bytes(range(1, 32)) * 3000,
    ],
    ids=["nul-late", "nuls-at-end", "png", "utf16", "controls"],
)
def test_binary_files_get_the_same_one_reason_in_pieces(data: bytes) -> None:
    expected = whole(data, "O5.nc", GENERIC)
    assert not expected.accepted and expected.rejections[0].rule in {"binary", "encoding"}
    assert pieces(data, list(range(4096, len(data), 4096)), "O5.nc", GENERIC) == expected


def test_a_program_over_the_size_limit_is_judged_by_its_size() -> None:
    rules = ValidationRules.for_dialect("laser-sim", max_size=50_000)
    data = laser_program(80_000, seed=14, number=6)
    verdict = pieces(data, list(range(8192, len(data), 8192)), "O6.nc", rules)
    assert verdict == whole(data, "O6.nc", rules)
    assert [r.rule for r in verdict.rejections] == ["size"]


def test_stripped_xon_xoff_bytes_make_the_delivered_program_differ() -> None:
    data = b"\x11" + laser_program(100_000, seed=15, number=7).replace(b"M5\n", b"M5\x13\n", 3)
    check = ProgramCheck(GENERIC)
    for start in range(0, len(data), 5000):
        check.feed(data[start : start + 5000])
    verdict = check.finish("O7.nc")
    full = validate_program(data, "O7.nc", GENERIC)
    assert check.changed and verdict.accepted
    assert verdict == dataclasses.replace(full, program=b"")
    assert full.program == data.replace(b"\x11", b"").replace(b"\x13", b"")
    assert any("removed 4 XON/XOFF" in w and "line 1" in w for w in verdict.warnings)

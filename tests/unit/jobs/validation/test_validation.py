"""Job validation: every rejection named by rule, line and column; binaries and bad names; real programs.

tests/corpus/gcode/*.nc carry their expectations in header comments, read from
the file itself (which is fed to the validator byte for byte):
    (expect: RULE LINE[:COLUMN])   one per rejection, LINE '-' when it has none; or (expect: accepted)
    (rules: {YAML flow mapping})   the ValidationRules, e.g. {dialect: fanuc}; default: generic
    (name: FILE)                   the upload's file name; default: the corpus file's own name
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.codecs.gcode import lex_lines, parse_program
from gateway.config.validation import ValidationRules
from gateway.jobs.validation.pipeline import MAX_REJECTIONS, Verdict, assemble, validate_program

CORPUS = Path(__file__).resolve().parents[3] / "corpus" / "gcode"
REAL_WORLD = Path("/work/shared/corpus/gcode")
HEADER = re.compile(r"[(;]\s*(expect|rules|name):\s*(.*?)\s*\)?\s*$")
CASES = sorted(CORPUS.glob("*.nc"))

GOOD = b"G21 G90\nG0 X10 Y10\nG1 X50 F1500\nM30\n"


def header(path: Path) -> tuple[list[str], dict[str, object], str]:
    expect: list[str] = []
    rules: dict[str, object] = {}
    name = path.name
    for line in path.read_bytes().decode("utf-8", errors="replace").splitlines():
        m = HEADER.search(line)
        if not m:
            continue
        key, value = m.groups()
        if key == "expect":
            expect.append(value)
        elif key == "rules":
            rules = yaml.safe_load(value)
        else:
            name = value
    return expect, rules, name


def located(verdict: Verdict) -> list[str]:
    return [
        f"{r.rule} {'-' if r.line is None else r.line}" + (f":{r.column}" if r.column is not None else "")
        for r in verdict.rejections
    ]


def matches(expected: str, got: str) -> bool:
    """`syntax 8` matches `syntax 8:11`; `syntax 8:11` only matches itself."""
    return got == expected or (":" not in expected and got.split(":")[0] == expected)


# --- the corpus of broken and valid programs ---------------------------------------------------


def test_corpus_has_twenty_broken_files_and_valid_ones_in_four_dialects() -> None:
    broken = [p for p in CASES if header(p)[0] != ["accepted"]]
    valid = [p for p in CASES if header(p)[0] == ["accepted"]]
    assert len(broken) >= 20
    assert len({header(p)[1].get("dialect", "generic") for p in valid}) >= 4
    for path in CASES:
        assert header(path)[0], f"{path.name} has no (expect: ...) header"


@pytest.mark.parametrize("path", CASES, ids=[p.stem for p in CASES])
def test_corpus_file_gets_exactly_the_rejections_its_header_promises(path: Path) -> None:
    expect, rules, name = header(path)
    data = path.read_bytes()
    verdict = validate_program(data, name, ValidationRules.model_validate(rules))
    got = located(verdict)
    if expect == ["accepted"]:
        assert verdict.accepted and got == [], verdict.reason
        assert verdict.estimate is not None and verdict.estimate.seconds and verdict.estimate.seconds > 0
        stripped = data.translate(None, b"\x11\x12\x13\x14")
        assert verdict.program == (stripped if verdict.program != data else data)
        return
    assert not verdict.accepted
    assert len(got) == len(expect), f"expected {expect}, got {got}: {verdict.reason}"
    for item in expect:
        assert any(matches(item, g) for g in got), f"expected {item}, got {got}:\n{verdict.reason}"
    for rejection in verdict.rejections:
        if rejection.line is not None:
            assert rejection.reason.startswith(f"line {rejection.line}")
    assert verdict.program == data


def test_xon_xoff_strip_delivers_the_program_without_them() -> None:
    data = (CORPUS / "ok-generic-xon-xoff-stripped.nc").read_bytes()
    verdict = validate_program(data, "job.nc", ValidationRules())
    assert verdict.accepted
    assert verdict.program == data.translate(None, b"\x11\x12\x13\x14") != data
    assert any("removed 3 XON/XOFF" in w for w in verdict.warnings)
    rejected = validate_program(data, "job.nc", ValidationRules(xon_xoff="reject"))
    assert [(r.rule, r.line, r.column) for r in rejected.rejections] == [
        ("xon-xoff", 3, 1),
        ("xon-xoff", 4, 13),
        ("xon-xoff", 6, 1),
    ]


def test_utf8_comments_switch() -> None:
    data = "(bend \u2013 90\u00b0)\nG1 X10 F100 (\u00e9t\u00e9)\nM30\n".encode()
    allowed = validate_program(data, "job.nc", ValidationRules(utf8_comments=True))
    assert allowed.accepted and allowed.warnings[0].startswith("UTF-8 text in comments (line 1 and 1 more)")
    refused = validate_program(data, "job.nc", ValidationRules(utf8_comments=False))
    assert [(r.rule, r.line, r.column) for r in refused.rejections] == [
        ("character", 1, 7),
        ("character", 2, 14),
    ]
    assert (
        "U+2013 (EN DASH)" in refused.rejections[0].reason
        and "(and 1 more on this line)" in refused.rejections[0].reason
    )


# --- binary and text encodings -------------------------------------------------------------------

JPEG = b"\xff\xd8\xff\xe0\x00\x10JFIF\x00\x01" + bytes(range(256)) * 40


@pytest.mark.parametrize(
    ("data", "rule", "fragment"),
    [
        (JPEG, "binary", "a JPEG image"),
        (b"\x89PNG\r\n\x1a\n" + b"\x00" * 64, "binary", "a PNG image"),
        (b"%PDF-1.7\n%\xe2\xe3\xcf\xd3\n", "binary", "a PDF document"),
        (b"PK\x03\x04" + b"\x14\x00" * 20, "binary", "ZIP archive"),
        (b"G1 X10\nM30\x00\n", "binary", "line 2, column 4: NUL byte (0x00): no G-code program holds one"),
        (b"G1 X10\nM30\n" + b"\x00" * 300, "binary", "line 3, column 1: the first of 300 NUL bytes (0x00)"),
        (bytes((i * 97 + 13) % 256 for i in range(5000)).replace(b"\x00", b"\x01"), "binary", "are not text"),
        ("\ufeffG1 X10\nM30\n".encode("utf-16-le"), "encoding", "UTF-16"),
        ("G1 X10\r\nM30\r\n".encode("utf-16-be"), "encoding", "UTF-16"),
        (b"", "empty", "the file is empty"),
        (b"\r\n \t\n\n", "empty", "only blank lines"),
    ],
    ids=[
        "jpeg",
        "png",
        "pdf",
        "zip",
        "nul",
        "nul-padding",
        "noise",
        "utf16-bom",
        "utf16-bare",
        "empty",
        "blank",
    ],
)
def test_one_clear_reason_for_files_that_are_not_text(data: bytes, rule: str, fragment: str) -> None:
    verdict = validate_program(data, "job.nc", ValidationRules())
    assert [r.rule for r in verdict.rejections] == [rule]
    assert fragment in verdict.rejections[0].reason
    assert verdict.estimate is None


def test_rejections_are_capped_with_a_count_of_the_rest() -> None:
    data = b"".join(b"G1 X1\x07\n" for _ in range(120)) + b"G1 Q\n" * 5
    verdict = validate_program(data, "job.nc", ValidationRules())
    assert len(verdict.rejections) == MAX_REJECTIONS
    assert [r.line for r in verdict.rejections[:3]] == [1, 2, 3]
    last = verdict.rejections[-1]
    assert last.rule == "more" and last.line is None
    # 120 BEL + 5 syntax + 1 missing end code = 126; 49 shown
    assert last.reason == "and 77 more rejections (character: 71, syntax: 5, end-code: 1)"


# --- file names ----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("name", "fragment"),
    [
        ("../x.nc", "path separator"),
        ("dir\\x.nc", "path separator"),
        ("/abs.nc", "path separator"),
        (".hidden.nc", "starts with a dot"),
        ("CON.nc", "Windows device name CON"),
        ("com1.txt", "Windows device name COM1"),
        ("nul", "Windows device name NUL"),
        ("a b.nc", "contains a space"),
        ("x.exe", "extension '.exe' is not allowed"),
        ("part", "a name without an extension"),
        ("x" * 196 + ".nc", "is 199 characters long; this controller takes at most 32"),
        ("part.nc.", "ends with a dot"),
        ("tab\tname.nc", "control character"),
        ("", "is empty"),
        ("pa:rt.nc", "is not a name this controller can hold"),
    ],
)
def test_file_names_the_controller_cannot_hold(name: str, fragment: str) -> None:
    verdict = validate_program(GOOD, name, ValidationRules())
    assert not verdict.accepted
    assert {r.rule for r in verdict.rejections} == {"file-name"}
    assert all(r.line is None for r in verdict.rejections)
    assert any(fragment in r.reason for r in verdict.rejections), verdict.reason


@pytest.mark.parametrize(
    ("name", "dialect", "ok"),
    [
        ("PART-1.nc", "generic", True),
        ("part_1.GCODE", "generic", True),
        ("O1234", "fanuc", True),
        ("PART_1.MPF", "sinumerik", True),
        ("_N_PART.SPF", "sinumerik", True),
        ("1PART.MPF", "sinumerik", False),
        ("PART_1.nc", "sinumerik", False),
        ("A" * 40 + ".ngc", "linuxcnc", True),
    ],
)
def test_file_name_rules_per_dialect(name: str, dialect: str, ok: bool) -> None:
    rules = ValidationRules.for_dialect(dialect, markers="optional", program_name="ignore")
    rejections = [r for r in validate_program(GOOD, name, rules).rejections if r.rule == "file-name"]
    assert (not rejections) == ok, rejections


# --- markers, end codes, names --------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "markers", "expected"),
    [
        ("%\nG1 X1 F1\nM30\n%\n", "require", []),
        ("G1 X1 F1\nM30\n", "require", [("start-marker", 1), ("end-marker", 2)]),
        ("%\nG1 X1 F1\nM30\n%\n", "forbid", [("forbidden-marker", 1), ("forbidden-marker", 4)]),
        ("%\nG1 X1 F1\nM30\n%\n", "optional", []),
        ("G1 X1 F1\nM30\n", "optional", []),
        ("\n\n%\nG1 X1 F1\nM30\n", "optional", [("end-marker", 5)]),
    ],
)
def test_marker_modes(text: str, markers: str, expected: list[tuple[str, int]]) -> None:
    rules = ValidationRules(markers=markers)  # type: ignore[arg-type]
    verdict = validate_program(text.encode(), "job.nc", rules)
    assert [(r.rule, r.line) for r in verdict.rejections] == expected


def test_lines_after_the_closing_percent_are_a_warning() -> None:
    verdict = validate_program(b"%\nG1 X1 F1\nM30\n%\ngarbage ( here\nmore\n", "job.nc", ValidationRules())
    assert verdict.accepted
    assert (
        "2 non-blank lines after the closing '%' at line 4 are ignored by the controller" in verdict.warnings
    )


@pytest.mark.parametrize(
    ("text", "end_code", "expected"),
    [
        ("G1 X1 F1\nM02\n", "last", []),
        ("G1 X1 F1\nM002 (end)\n\n; done\n", "last", []),
        ("G1 X1 F1 M30\n", "last", []),
        ("G1 X1 F1\nM30\nG0 X0\n", "last", [("end-code", 3)]),
        ("G1 X1 F1\nM30\nG0 X0\n", "anywhere", []),
        ("G1 X1 F1\n(no end)\n", "anywhere", [("end-code", 2)]),
        ("G1 X1 F1\n", "optional", []),
        ("G1 X1 F1\n/M30\n", "anywhere", [("end-code", 2)]),
    ],
)
def test_end_code_modes(text: str, end_code: str, expected: list[tuple[str, int]]) -> None:
    rules = ValidationRules(end_code=end_code)  # type: ignore[arg-type]
    verdict = validate_program(text.encode(), "job.nc", rules)
    assert [(r.rule, r.line) for r in verdict.rejections] == expected


def test_configured_end_codes_compare_by_value() -> None:
    rules = ValidationRules(end_codes=["m017"])
    assert rules.end_codes == ("M17",)
    assert validate_program(b"G1 X1 F1\nM17\n", "job.nc", rules).accepted
    assert not validate_program(b"G1 X1 F1\nM30\n", "job.nc", rules).accepted


def test_program_name_must_match_and_require() -> None:
    fanuc = ValidationRules.for_dialect("fanuc")
    program = b"%\nO0012 (PLATE)\nG1 X1 F1\nM30\n%\n"
    assert validate_program(program, "O12.nc", fanuc).accepted
    assert validate_program(program, "o0012", fanuc).program_name == "O0012"
    wrong = validate_program(program, "PLATE.nc", fanuc)
    assert [(r.rule, r.line) for r in wrong.rejections] == [("program-name", 2)]
    assert "must be named O0012 or O0012.nc, not 'PLATE.nc'" in wrong.rejections[0].reason
    unnamed = b"%\nG1 X1 F1\nM30\n%\n"
    assert validate_program(unnamed, "PLATE.nc", fanuc).accepted
    required = validate_program(unnamed, "PLATE.nc", fanuc.model_copy(update={"program_name": "require"}))
    assert [r.rule for r in required.rejections] == ["program-name"]
    header = validate_program(b"%O77\nG1 X1 F1\nM30\n%\n", "O77.nc", fanuc)
    assert header.accepted and header.program_name == "O0077"
    sinumerik = ValidationRules.for_dialect("sinumerik", markers="optional", program_name="must-match")
    named = validate_program(b"%_N_PART_1_MPF\nG1 X1 F1\nM30\n%\n", "part_1.mpf", sinumerik)
    assert named.accepted and named.program_name == "_N_PART_1_MPF"


def test_macros_warn_or_reject() -> None:
    text = b"#1 = 5\nG1 X[#1 * 2] F100\nG1 X20\nM2\n"
    warned = validate_program(text, "job.ngc", ValidationRules.for_dialect("linuxcnc"))
    assert warned.accepted
    assert warned.warnings[0].startswith("line 1, column 1: parameters (#) are not supported here")
    assert warned.estimate is not None and not warned.estimate.exact
    assert "lines 1, 2: could not be read, so not estimated" in warned.estimate.notes
    rejected = validate_program(text, "job.nc", ValidationRules.for_dialect("laser-sim"))
    assert [(r.rule, r.line) for r in rejected.rejections] == [("syntax", 1), ("syntax", 2)]


def test_unknown_codes_are_warnings_not_rejections() -> None:
    verdict = validate_program(b"G1 X1 F1\nG81 X1 Y1 Z-1 R1\nG80\nM300\nM30\n", "job.nc", ValidationRules())
    assert verdict.accepted
    assert "line 2: canned cycle G81 is not estimated" in verdict.warnings


def test_verdict_as_dict_is_json() -> None:
    verdict = validate_program(b"G1 X1\x07\n", "a b.nc", ValidationRules())
    d = json.loads(json.dumps(verdict.as_dict()))
    assert d["accepted"] is False
    assert [r["rule"] for r in d["rejections"]] == [
        "file-name",
        "character",
        "end-code",
    ]  # by line, then column
    assert d["rejections"][1] == {
        "rule": "character",
        "reason": "line 1, column 6: character 0x07 (BEL) is not allowed",
        "line": 1,
        "column": 6,
    }
    assert d["estimate"]["cut_mm"] == 1.0


def test_assemble_reads_programs_like_parse_program() -> None:
    for path in [*CASES, *(sorted(REAL_WORLD.glob("*")) if REAL_WORLD.is_dir() else [])]:
        text = path.read_bytes().decode("utf-8", errors="replace")
        try:
            expected = parse_program(text)
        except ValueError:
            continue
        parsed = assemble(lex_lines(text))
        assert parsed.program == expected, path.name
        assert not parsed.errors


# --- properties ----------------------------------------------------------------------------------


@settings(max_examples=150, deadline=None)
@given(data=st.binary(max_size=400), name=st.text(max_size=40))
def test_validator_never_raises_and_locates_within_the_file(data: bytes, name: str) -> None:
    verdict = validate_program(data, name, ValidationRules())
    assert verdict.accepted == (not verdict.rejections)
    assert len(verdict.rejections) <= MAX_REJECTIONS
    lines = data.count(b"\n") + 1
    for r in verdict.rejections:
        assert r.line is None or 1 <= r.line <= lines
        assert r.reason


LINES = ["G21 G90", "G0 X10 Y10 (start)", "M3 S1000", "G1 X50 Y10 F1200", "G2 X60 Y20 I0 J10", "M5"]


@settings(max_examples=150, deadline=None)
@given(
    line=st.integers(0, len(LINES) - 1),
    where=st.floats(0, 1),
    bad=st.sampled_from([0x01, 0x07, 0x08, 0x1B, 0x7F]),
)
def test_a_stray_control_byte_is_found_at_its_line_and_column(line: int, where: float, bad: int) -> None:
    lines = list(LINES)
    column = math.floor(where * len(lines[line]))
    lines[line] = lines[line][:column] + chr(bad) + lines[line][column:]
    data = ("\n".join(lines) + "\nM30\n").encode()
    verdict = validate_program(data, "job.nc", ValidationRules())
    assert [(r.rule, r.line, r.column) for r in verdict.rejections] == [("character", line + 1, column + 1)]
    assert f"0x{bad:02X}" in verdict.rejections[0].reason


# --- the real-world corpus ---------------------------------------------------------------------


def real(name: str) -> bytes:
    if not REAL_WORLD.is_dir():
        pytest.skip(f"{REAL_WORLD} is missing: the shared real-world G-code corpus is not on this machine")
    return (REAL_WORLD / name).read_bytes()


@pytest.mark.parametrize("dialect", ["linuxcnc", "generic"])
def test_real_world_sunrise_pie_laser(dialect: str) -> None:
    verdict = validate_program(
        real("sunrise_pie_laser.nc"), "sunrise_pie_laser.nc", ValidationRules.for_dialect(dialect)
    )
    got = [(r.rule, r.line) for r in verdict.rejections]
    # Nested parentheses in two comments, and no M2/M30 at all (the program's last line is 57).
    expected = [("syntax", 10), ("syntax", 15), ("end-code", 57)]
    if dialect == "linuxcnc":  # ASCII only: every en dash in a comment is named (utf8_comments is off)
        expected += [("character", line) for line in (2, 3, 4, 5, 8, 18, 55)]
    assert sorted(got) == sorted(expected)
    en_dash = [r for r in verdict.rejections if r.rule == "character"]
    assert all("U+2013 (EN DASH)" in r.reason and r.column == 6 for r in en_dash if r.line != 18)
    assert verdict.estimate is not None and verdict.estimate.seconds is not None


@pytest.mark.parametrize("dialect", ["linuxcnc", "generic"])
def test_real_world_butterfly_nurbs(dialect: str) -> None:
    verdict = validate_program(real("butterfly.ngc"), "butterfly.ngc", ValidationRules.for_dialect(dialect))
    assert verdict.accepted, verdict.reason
    estimate = verdict.estimate
    assert estimate is not None and not estimate.exact
    nurbs = [n for n in estimate.notes if "NURBS" in n]
    assert [n.split(":")[0] for n in nurbs] == [
        "line 9",
        "line 15",
        "line 27",
        "line 47",
        "line 67",
        "line 86",
    ]
    assert estimate.cut_mm == pytest.approx(5 * 7.0)  # the plunges G1 Z-5 from Z2; the curves are not counted
    assert estimate.extents is not None and estimate.extents.max_z == 30.0


@pytest.mark.parametrize("dialect", ["linuxcnc", "generic"])
def test_real_world_hole_circle_inches_and_canned_cycle(dialect: str) -> None:
    verdict = validate_program(
        real("hole-circle.ngc"), "hole-circle.ngc", ValidationRules.for_dialect(dialect)
    )
    assert verdict.accepted, verdict.reason
    estimate = verdict.estimate
    assert estimate is not None and not estimate.exact
    assert estimate.notes == ("line 10: canned cycle G81 (with polar words) is not estimated",)
    assert estimate.rapid_mm == pytest.approx(1.5 * 25.4)  # G0 X1.5 in inches


@pytest.mark.parametrize("dialect", ["linuxcnc", "generic"])
def test_real_world_laser_cut_circle_by_hand(dialect: str) -> None:
    rules = ValidationRules.for_dialect(dialect)
    verdict = validate_program(real("laser_cut_circle.gcode"), "laser_cut_circle.gcode", rules)
    assert verdict.accepted, verdict.reason
    e = verdict.estimate
    assert e is not None and e.exact and e.notes == ()
    # From (0,0,0): G0 Z5, G0 X0 Y0 (no move), G1 Z-1 F100 (6 mm), G2 full circle r=5 at F200,
    # G0 Z5 (6 mm), G0 X0 Y0 (no move).
    circle = 2 * math.pi * 5
    assert e.cut_mm == pytest.approx(6 + circle) and e.rapid_mm == pytest.approx(11.0)
    assert e.seconds == pytest.approx(6 / 100 * 60 + circle / 200 * 60 + 11 / rules.rapid_feed * 60)
    assert e.extents is not None and e.extents.as_dict() == pytest.approx(
        {"min_x": -5.0, "max_x": 5.0, "min_y": 0.0, "max_y": 10.0, "min_z": -1.0, "max_z": 5.0}
    )


@pytest.mark.parametrize("dialect", ["linuxcnc", "generic"])
def test_real_world_plasma_with_dwells(dialect: str) -> None:
    data = real("plasma_lid_wing.gcode")
    verdict = validate_program(data, "plasma_lid_wing.gcode", ValidationRules.for_dialect(dialect))
    assert verdict.accepted, verdict.reason
    e = verdict.estimate
    assert e is not None and e.exact
    dwells = [float(m) for m in re.findall(rb"G4 P([0-9.]+)", data)]
    assert len(dwells) > 20 and e.dwell_s == pytest.approx(sum(dwells))
    assert e.seconds is not None and e.seconds > e.dwell_s + e.cut_mm / 450 * 60 - 1e-6
    assert (
        e.extents is not None
        and e.extents.min_x == 0.0
        and e.extents.max_y == pytest.approx(654.2087998459664)
    )


def test_real_world_every_file_gets_a_verdict_under_every_dialect() -> None:
    if not REAL_WORLD.is_dir():
        pytest.skip(f"{REAL_WORLD} is missing: the shared real-world G-code corpus is not on this machine")
    for path in sorted(REAL_WORLD.iterdir()):
        if path.suffix == ".md":
            continue
        for dialect in ("generic", "fanuc", "linuxcnc", "sinumerik", "laser-sim"):
            verdict = validate_program(path.read_bytes(), path.name, ValidationRules.for_dialect(dialect))
            assert verdict.estimate is not None
            assert all(r.reason for r in verdict.rejections)


def test_columns_after_a_removed_character_point_into_the_file() -> None:
    verdict = validate_program(b"G1\x07 X10 Y F1 M98\nM30\n", "job.nc", ValidationRules(forbid_codes=["M98"]))
    assert [(r.rule, r.line, r.column) for r in verdict.rejections] == [
        ("character", 1, 3),
        ("syntax", 1, 11),
    ]
    verdict = validate_program(b"G1\x07 X10 M98\nM30\n", "job.nc", ValidationRules(forbid_codes=["M98"]))
    assert [(r.rule, r.line, r.column) for r in verdict.rejections] == [
        ("character", 1, 3),
        ("forbidden-code", 1, 9),
    ]


_PIECES = [
    "%", "%O1234 (X)", "O100 (NAME)", "N10 G1 X1 Y2", "G0 X5", "G1 X1.5 F300", "M30", "M2", "M02", "/M30",
    "G2 X10 Y0 I5 J0", "G3 X1 Y1 R2", "G4 P1", "G92 X0 Y0", "M8", "G28", "G91", "G20", "(comment only)",
    "; tail", "", "  ", "X1 Y2 Z3", "#1=5", "G1 X[1+2]", "G5.2 X1 Y2", "N20 M30", "X.5 Y-.5", "G1 A5", "M0",
    "G53 X0", "G93 G1 X1 F2", "o100 sub", "G1 X" + "9" * 320,
]  # fmt: skip


@settings(max_examples=200, deadline=None)
@given(
    lines=st.lists(st.sampled_from(_PIECES), max_size=25),
    crlf=st.booleans(),
    dialect=st.sampled_from(["laser-sim", "fanuc", "generic", "linuxcnc"]),
)
def test_the_one_pass_reading_agrees_with_assemble_and_estimate_program(
    lines: list[str], crlf: bool, dialect: str
) -> None:
    """validate_program reads a program in one pass without keeping its blocks (for 50 MB programs);
    its estimate and end-code verdict are what the block-by-block reading gives."""
    from gateway.jobs.validation.estimate import estimate_program

    text = ("\r\n" if crlf else "\n").join(lines) + "\n"
    rules = ValidationRules.model_validate({"dialect": dialect, "forbid_codes": ["M8"]})
    verdict = validate_program(text.encode(), "O100.nc", rules)
    parsed = assemble(lex_lines(text))
    if verdict.estimate is not None and not any(
        r.rule in ("size", "binary", "encoding") for r in verdict.rejections
    ):
        expected = estimate_program(
            parsed.program, rapid_feed_mm_min=rules.rapid_feed, default_feed_mm_min=rules.default_feed,
            dwell_p=rules.dwell_p,
        )  # fmt: skip
        got = verdict.estimate
        assert (got.seconds, got.cut_mm, got.blocks, got.extents) == (
            expected.seconds,
            expected.cut_mm,
            expected.blocks,
            expected.extents,
        )
    forbidden_lines = sorted(r.line for r in verdict.rejections if r.rule == "forbidden-code")
    expected_lines = sorted(
        b.line for b in parsed.program.blocks for w in b.words if w.letter == "M" and w.value == 8.0
    )
    assert forbidden_lines == expected_lines

"""The fast paths of validation (gateway.jobs.fast_read) give exactly the general path's verdicts.

Each program is validated three times: with the fast path forced off, with the
regex fast path alone, and with the compiled reader (`_plain.c`) in front of it.
The verdicts must be equal: rejections, warnings, estimate numbers to the bit,
extents, name.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bench.gcode_gen import laser_program
from gateway.config.validation import ValidationRules
from gateway.jobs.validation import compiled, fast_read, text_checks
from gateway.jobs.validation.pipeline import Verdict, validate_program
from tests.unit.jobs.validation.test_validation import CASES, header

DIALECTS = ("generic", "fanuc", "linuxcnc", "sinumerik", "laser-sim")


@contextmanager
def fast(enabled: bool, chunk: int | None = None, compiled_reader: bool = False) -> Iterator[None]:
    saved = fast_read._ENABLED, fast_read._CHUNK, fast_read._COMPILED
    fast_read._ENABLED = enabled
    fast_read._CHUNK = chunk or saved[1]
    fast_read._COMPILED = compiled_reader
    try:
        yield
    finally:
        fast_read._ENABLED, fast_read._CHUNK, fast_read._COMPILED = saved


def both(data: bytes, name: str, rules: ValidationRules, chunk: int | None = None) -> Verdict:
    """The general path, the regex fast path and the compiled reader agree; the latter's verdict."""
    with fast(False):
        general = validate_program(data, name, rules)
    with fast(True, chunk):
        quick = validate_program(data, name, rules)
    assert quick == general
    if compiled.plain is None:
        return quick
    with fast(True, chunk, compiled_reader=True):
        native = validate_program(data, name, rules)
    assert native == general
    return native


needs_compiled = pytest.mark.skipif(compiled.plain is None, reason="the compiled reader is not built here")


def test_the_compiled_reader_is_built_where_a_compiler_is() -> None:
    """`pip install -e .` builds `_plain.c`; a silent fallback would cost thirty times the time."""
    if compiled.plain is None and not (os.environ.get("CI") or shutil.which("cc") or shutil.which("gcc")):
        pytest.skip("no C compiler here: the pure-Python readers do the work")
    assert compiled.plain is not None, (
        "gateway/jobs/validation/_plain.c was not built: run `pip install -e .` again"
    )


@pytest.mark.parametrize("path", CASES, ids=lambda p: p.name)
@pytest.mark.parametrize("dialect", [None, *DIALECTS])
def test_every_corpus_file_reads_the_same(path: Path, dialect: str | None) -> None:
    _, rules, name = header(path)
    chosen = (
        ValidationRules.model_validate(rules) if dialect is None else ValidationRules.for_dialect(dialect)
    )
    both(path.read_bytes(), name, chosen)


@pytest.mark.parametrize("chunk", [None, 64, 1000])
def test_a_laser_program_reads_the_same_in_any_chunks(chunk: int | None) -> None:
    data = laser_program(60_000, seed=7, number=12)
    verdict = both(data, "O12.nc", ValidationRules.for_dialect("laser-sim"), chunk)
    assert verdict.accepted and verdict.estimate is not None and verdict.estimate.seconds


def test_the_fast_path_reads_most_of_a_plain_program() -> None:
    """Not a timing: the fast reader must actually take plain blocks (else the speed-up is gone)."""
    data = laser_program(60_000, seed=8, number=13)
    rules = ValidationRules.for_dialect("laser-sim")
    taken = 0
    original = fast_read._FastReader.store

    def counting(self: fast_read._FastReader, n: int, *args: object) -> None:
        nonlocal taken
        taken += n
        original(self, n, *args)  # type: ignore[arg-type]

    fast_read._FastReader.store = counting  # type: ignore[method-assign]
    try:
        with fast(True):
            verdict = validate_program(data, "O13.nc", rules)
    finally:
        fast_read._FastReader.store = original  # type: ignore[method-assign]
    assert verdict.estimate is not None
    assert taken > 0.9 * verdict.estimate.blocks


@needs_compiled
def test_the_compiled_reader_reads_most_of_a_plain_program() -> None:
    """Not a timing: the compiled reader must take nearly every block of a nest itself."""
    data = laser_program(60_000, seed=9, number=14)
    rules = ValidationRules.for_dialect("laser-sim")
    assert compiled.plain is not None
    original, taken = compiled.plain.read_rows, 0

    def counting(*args: object) -> tuple[int, int, int, int, int, bool]:
        nonlocal taken
        result = original(*args)  # type: ignore[arg-type]
        taken += result[2]
        return result  # type: ignore[no-any-return]

    compiled.plain.read_rows = counting
    try:
        with fast(True, compiled_reader=True):
            verdict = validate_program(data, "O14.nc", rules)
    finally:
        compiled.plain.read_rows = original
    assert verdict.estimate is not None
    assert taken > 0.99 * verdict.estimate.blocks


@needs_compiled
@pytest.mark.parametrize(
    "text",
    [
        "G1 X0.1234567890123456789012 Y1\n",  # more digits than the exact conversion takes
        "G1 X123456789012345678901234567890 Y2\n",  # 30 integer digits
        "G1 X1234567890123456789012345678901 Y2\n",  # 31: not a plain block
        "G1 X0.00000000000000000000000001 Y1\n",  # a fraction beyond 1e-22
        "G1 X9007199254740993 Y1\n",  # above 2**53
        "G1 X-0 Y-0.0 M100\n",  # negative zeros, an M code beyond the table
        "G1 X1 Y1 M123456789\nG1 X1 Y1 M1234567890\n",
        "G1 X1\r\nG1 Y2\r\r\nG1 X3",  # CR LF, a stray CR, no final LF
        "G1 X1 Y1 S.\nG1 X2 S-.5\n",
    ],
)
def test_awkward_numbers_and_lines_read_the_same(text: str) -> None:
    program = "G21 G90\nG0 X0 Y0 Z0\nG1 F1000\n" + text + "\nG1 X5 Y5\nM30\n"
    both(program.encode(), "job.nc", ValidationRules.for_dialect("generic"))


@pytest.mark.parametrize(
    "data",
    [
        b"",
        b"\n",
        b"G1\n",
        b"G1 X1\r\nG2",
        b"G1\rX\n",
        b"ab\tc\n\x7f\n",
        b"a\r",
        b"\xc3\xa9\n",
        b"x" * 300 + b"\n",
        b"G1\x00X\n\x00\n",
        b"\x00",
        b"\x11G1\n",
    ],
)
def test_text_stats_agree_with_the_python_reading(data: bytes, monkeypatch: pytest.MonkeyPatch) -> None:
    native = text_checks.text_stats(data)
    monkeypatch.setattr(compiled, "plain", None)
    assert text_checks.text_stats(data) == native


# --- generated programs ------------------------------------------------------------------------

NUMBERS = st.one_of(
    st.integers(-3000, 3000).map(str),
    st.decimals(-1e6, 1e6, allow_nan=False, allow_infinity=False, places=25).map(lambda d: f"{d:f}"),
    st.floats(-3000, 3000, allow_nan=False).map(lambda v: f"{v:.3f}"),
    st.sampled_from(
        ["0", "-0", "0.", ".5", "-.5", "10.", "1e3", "1.2.3", "1-2", "", "-", "9" * 40, "+1", "50000"]
    ),
)
SMALL = st.integers(-50, 50).map(str)


@st.composite
def arc_block(draw: st.DrawFn) -> str:
    """Arcs the estimator takes without comment: full circles by I/J, and R arcs with a short chord."""
    g = draw(st.sampled_from(["G2", "G3", ""]))
    if draw(st.booleans()):
        centre = [f"I{draw(SMALL)}", f"J{draw(SMALL)}"]
        return " ".join([g, *draw(st.lists(st.sampled_from(centre), min_size=1, unique=True))]).strip()
    x, y = draw(SMALL), draw(SMALL)
    r = draw(st.sampled_from(["100", "-100", "75.5", "-80"]))
    z = f" Z{draw(SMALL)}" if draw(st.booleans()) else ""  # a helix
    feed = f" F{draw(st.sampled_from(['800', '50000', '1200']))}" if draw(st.booleans()) else ""
    return f"{g} X{x} Y{y}{z} R{r}{feed}".strip()


PLAIN_LETTERS = "XYZIJRF"


@st.composite
def plain_block(draw: st.DrawFn) -> str:
    g = draw(st.sampled_from(["", "G0", "G1", "G2", "G3", "G00", "G01", "G02"]))
    letters = draw(st.lists(st.sampled_from(PLAIN_LETTERS), max_size=5, unique=True))
    letters.sort(key=PLAIN_LETTERS.index)
    words = [g] if g else []
    words += [f"{letter}{draw(NUMBERS)}" for letter in letters]
    if draw(st.booleans()):
        words.append(draw(st.sampled_from(["M3", "M5", "M8", "M30", "M2", "M0", "M1", "M98", "M03"])))
    if draw(st.booleans()):
        words.append(f"S{draw(NUMBERS)}")
    sep = draw(st.sampled_from(["", " ", " ", " ", "  ", "\t"]))
    return sep.join(w for w in words)


OTHER = st.sampled_from(
    [
        "G90",
        "G91",
        "G20",
        "G21",
        "G17",
        "G18",
        "G19",
        "G90.1",
        "G91.1",
        "G93",
        "G94",
        "G95",
        "G92 X0 Y0",
        "G92 X10",
        "G28",
        "G4 P1",
        "G54",
        "G55",
        "G41",
        "G40",
        "G5.2 X1 Y1",
        "G81 X1 Y1 Z-1 R1",
        "G80",
        "M30",
        "M2",
        "M0",
        "%",
        "%O123",
        "O100 (PART)",
        "(comment)",
        "; comment",
        "/G1 X5",
        "N10 G1 X1",
        "g1 x2 y3",
        "#1=5",
        "G1 X[1+2]",
        "X",
        "Q5",
        "G1 A10",
        "G1 ^5 @2",
        "G1 X1 (c) Y2",
        "",
        "   ",
        "G2 X1 Y1 P2 I1",
        "G3 I5",
        "G2 R-5 X1",
        "G1 X1e400",
        "M98 P100",
        "G1 X1 X2",
        "G1 G0 X1",
        "F0",
        "F99999",
        "G1 X10 Y10 F50000",
        "G10 L2 P1 X1",
        "G53 X1",
        "G1 U5",
        "G16",
        "G0 X1 Y1 Z1",
    ]
)
LINE = st.one_of(plain_block(), plain_block(), arc_block(), arc_block(), OTHER)


@st.composite
def program(draw: st.DrawFn) -> tuple[bytes, ValidationRules]:
    lines = draw(st.lists(LINE, max_size=40))
    if draw(st.booleans()):
        lines = ["G21 G90", "G0 X0 Y0 Z0", "G1 F1000", *lines]
    eol = draw(st.sampled_from(["\n", "\r\n"]))
    text = eol.join(lines) + draw(st.sampled_from([eol, ""]))
    dialect = draw(st.sampled_from(DIALECTS))
    extra: dict[str, object] = {}
    if draw(st.booleans()):
        extra["forbid_codes"] = draw(st.lists(st.sampled_from(["G2", "G0", "M3", "M98", "G92"]), max_size=2))
    if draw(st.booleans()):
        extra["end_codes"] = draw(
            st.lists(st.sampled_from(["M30", "M2", "M5", "G1"]), min_size=1, max_size=2)
        )
    if draw(st.booleans()):
        extra["default_feed"] = 500.0
    rules = ValidationRules.for_dialect(dialect, **extra)
    return text.encode(), rules


@settings(max_examples=1000, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(program(), st.sampled_from([None, 16, 200]))
def test_generated_programs_read_the_same(case: tuple[bytes, ValidationRules], chunk: int | None) -> None:
    data, rules = case
    both(data, "job.nc", rules, chunk)


@needs_compiled
@settings(max_examples=2000, deadline=None)
@given(
    st.lists(
        st.sampled_from(
            [
                b"G1 X1.5",
                b"\n",
                b"\r",
                b"\r\n",
                b"\t",
                b"\x00",
                b"\x7e",
                b"\x7f",
                b"\x80",
                b"\x1f",
                b"\x20",
                b"\xc3\xa9",
                b"\x11",
                bytes(range(0x20, 0x7F)),
            ]
        ),
        max_size=60,
    )
)
def test_text_stats_agree_with_the_python_reading_on_any_bytes(parts: list[bytes]) -> None:
    data = b"".join(parts)
    native = text_checks.text_stats(data)
    saved, compiled.plain = compiled.plain, None
    try:
        assert text_checks.text_stats(data) == native
    finally:
        compiled.plain = saved


GCODE_ALPHABET = "GXYZIJRFMS0123456789.- \n\r\t%()/;Na"


@settings(max_examples=500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.one_of(st.text(alphabet=GCODE_ALPHABET, max_size=400).map(str.encode), st.binary(max_size=200)),
    st.sampled_from(DIALECTS),
)
def test_arbitrary_text_reads_the_same_and_never_crashes(data: bytes, dialect: str) -> None:
    """Fuzzing the compiled reader against the Python readers with G-code's own letters in any order."""
    both(b"G21 G90\nG0 X0 Y0 Z0\nG1 F1000\n" + data, "job.nc", ValidationRules.for_dialect(dialect))

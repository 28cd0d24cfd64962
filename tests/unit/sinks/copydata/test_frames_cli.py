"""`cnc-gateway frames decode|encode`, in-process: the docs' examples, round trips, clear errors."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from gateway.cli.main import main

ROOT = Path(__file__).resolve().parents[4]
DOC = ROOT / "docs" / "copydata.md"
MAPPING = str(ROOT / "mappings" / "laser-sim.yaml")
BLOCK = re.compile(r"<!-- copydata-example: (?P<name>[\w-]+) -->\s*```\w*\n(?P<body>.*?)```", re.DOTALL)
WORKED_HEX = (
    "02 00 00 00 28 00 00 00 01 00 08 00 00 00 00 00 00 4a 93 40 05 00 04 00 2a 00 00 00 "
    "07 00 01 00 01 09 00 0b 00 54 65 69 6c 2d c3 98 33 2e 6e 63"
)


def doc_example(name: str, tmp_path: Path) -> Path:
    """The example's `offset | bytes | field` table, saved as a file, as a developer would paste it."""
    for match in BLOCK.finditer(DOC.read_text(encoding="utf-8")):
        if match["name"] == name:
            path = tmp_path / f"{name}.txt"
            path.write_text(match["body"], encoding="utf-8")
            return path
    raise AssertionError(f"no example {name} in {DOC}")


def run(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    code = main(["frames", *args])
    out, err = capsys.readouterr()
    return code, out, err


def test_decode_the_worked_example_of_the_docs_with_names_from_the_mapping(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = run(capsys, "decode", str(doc_example("tcp", tmp_path)), "--mapping", MAPPING)
    assert code == 0, err
    assert out.splitlines() == [
        "frame at byte 0: dwData = 2 (several variables), cbData = 40",
        "  item 1 at byte 8: id 1 (Axes/X/Position, Double), N = 8: 1234.5",
        "  item 2 at byte 20: id 5 (Program/Block, UInt32), N = 4: 42",
        "  item 3 at byte 28: id 7 (Laser/On, Boolean), N = 1: true",
        '  item 4 at byte 33: id 9 (Program/Name, String), N = 11: "Teil-Ø3.nc"',
        "1 frame, 48 bytes",
    ]


def test_decode_bare_lpdata_as_wm_copydata_carries_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, _ = run(capsys, "decode", str(doc_example("lpdata", tmp_path)), "--dwdata", "2",
                       "--types", "1=Double:X,5=UInt32:Block,7=Boolean:On,9=String:Name")  # fmt: skip
    assert code == 0
    assert "item 1 at byte 0: id 1 (X, Double), N = 8: 1234.5" in out
    assert 'item 4 at byte 25: id 9 (Name, String), N = 11: "Teil-Ø3.nc"' in out


def test_decode_without_types_still_takes_the_frame_apart(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "decode", WORKED_HEX)
    assert code == 0
    assert "item 2 at byte 20: id 5, N = 4: 2a 00 00 00" in out


def test_encode_builds_the_docs_example_and_decode_reads_it_back(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "encode", "--mapping", MAPPING,
                         "Axes/X/Position=1234.5", "5=42", "Laser/On=true",
                         "Program/Name=Teil-Ø3.nc")  # fmt: skip
    assert code == 0, err
    assert out.strip() == WORKED_HEX
    code, out, _ = run(capsys, "decode", out.strip(), "--mapping", MAPPING)
    assert code == 0 and "N = 8: 1234.5" in out and '"Teil-Ø3.nc"' in out


def test_encode_with_other_widths_and_inline_types(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out_file = tmp_path / "frame.bin"
    code, out, _ = run(capsys, "encode", "--widths", "1,4", "1:Double=1234.5", "--lpdata")
    assert code == 0 and out.strip() == "01 08 00 00 00 00 00 00 00 00 4a 93 40"  # as docs/copydata.md says
    code, _, _ = run(capsys, "encode", "--widths", "1,4", "1:Double=1234.5", "-o", str(out_file))
    assert code == 0 and out_file.read_bytes()[:4] == b"\x01\x00\x00\x00"
    code, out, _ = run(capsys, "decode", str(out_file), "--widths", "1,4", "--types", "1=Double")
    assert code == 0 and "id 1 (id 1, Double), N = 8: 1234.5" in out


def test_encode_arrays_strings_and_datetimes_round_trip(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "encode", "11:String[]=[\"Gas low\",\"Düse\"]",
                         "12:DateTime=2024-01-01T00:00:00Z", "13:Double[]=[0.5,100]",
                         "--encoding", "utf-16-le")  # fmt: skip
    assert code == 0, err
    code, out, _ = run(capsys, "decode", out, "--encoding", "utf-16-le",
                       "--types", "11=String[],12=DateTime,13=Double[]")  # fmt: skip
    assert code == 0
    assert '["Gas low", "Düse"]' in out and "2024-01-01T00:00:00Z" in out and "[0.5, 100.0]" in out


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (["encode", "7=1"], "id 7 has no type"),
        (["encode", "--mapping", MAPPING, "Feed/Override=200000"], "does not fit UInt16"),
        (["encode", "--mapping", MAPPING, "Nope/Path=1"], "'Nope/Path' is not a variable with a copydata id"),
        (["encode", "--dwdata", "1", "1:Double=1", "2:Double=2"], "--dwdata 1 carries exactly one variable"),
        (["decode", "0g"], "not hex"),
        (["decode", "--widths", "3,2", "00"], "--widths '3,2'"),
        (["decode", "00", "--encoding", "utf-16"], "byte-order mark"),
        (
            ["decode", "00", "--mapping", MAPPING, "--target", "nope"],
            "no copydata target 'nope' (targets: nesting)",
        ),
    ],
)
def test_bad_input_gets_a_clear_error(
    args: list[str], fragment: str, capsys: pytest.CaptureFixture[str]
) -> None:
    code, _, err = run(capsys, *args)
    assert code == 2 and fragment in err and "Traceback" not in err


@pytest.mark.parametrize(
    ("hex_text", "fragment"),
    [
        ("03 00 00 00 00 00 00 00", "dwData 3 is neither 1"),
        ("01 00 00 00 08 00 00 00 01 00", "stream ended 10 bytes into a frame"),
        ("02 00 00 00 05 00 00 00 01 00 09 00 00", "declares 9 data bytes but only 1 remain"),
    ],
)
def test_malformed_frames_are_named_with_their_offset(
    hex_text: str, fragment: str, capsys: pytest.CaptureFixture[str]
) -> None:
    code, _, err = run(capsys, "decode", hex_text)
    assert code == 1 and fragment in err and "Traceback" not in err


README = ROOT / "README.md"


def readme_section() -> str:
    text = README.read_text(encoding="utf-8")
    start = text.index("## COPYDATA for nesting software")
    return text[start : text.index("\n## ", start + 1)]


def test_the_readme_worked_example_is_the_docs_example(capsys: pytest.CaptureFixture[str]) -> None:
    section = readme_section()
    block = section.split("as one TCP frame of 48 bytes:\n\n```text\n", 1)[1].split("```", 1)[0]
    data = bytearray()
    for line in block.splitlines():
        for token in line.split():
            if len(token) != 2 or any(c not in "0123456789abcdef" for c in token):
                break  # the annotation starts
            data.append(int(token, 16))
    assert bytes(data).hex(" ") == WORKED_HEX
    code, out, _ = run(capsys, "decode", bytes(data).hex(), "--mapping", MAPPING)
    assert code == 0 and '"Teil-Ø3.nc"' in out and "1234.5" in out


def test_the_readme_target_example_is_a_valid_configuration() -> None:
    import yaml

    from gateway.sinks.copydata.config import MachineCopydata

    section = readme_section()
    block = section.split("```yaml\ncopydata:\n", 1)[1].split("```", 1)[0]
    parsed = MachineCopydata.model_validate(yaml.safe_load("copydata:\n" + block)["copydata"])
    (target,) = parsed.targets
    assert (target.transport, target.listen_port, target.mode, target.max_rate) == (
        "tcp-server",
        5020,
        "batch",
        50,
    )

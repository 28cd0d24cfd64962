"""The configuration reads the same with libyaml's parser as with PyYAML's (config/loader.py `_compose`).

libyaml is only there for speed (start-up with thousands of variables): every shipped
mapping and every corpus file must give the same data, the same line of every key,
and the same errors, whichever parser composed it.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from gateway.config import loader
from gateway.errors import ConfigError

ROOT = Path(__file__).resolve().parents[3]
FILES = sorted([*ROOT.glob("mappings/*.yaml"), *ROOT.glob("tests/corpus/mappings/*.yaml")])


def _read(path: Path) -> tuple[object, object]:
    try:
        located = loader.read_yaml(path, {})
    except ConfigError as exc:
        return "error", [(i.line, i.key, i.message) for i in exc.issues]
    return located.data, located.lines


def test_libyaml_is_there() -> None:
    assert loader._FAST_LOADER is not None  # PyYAML built with libyaml (the wheels are)


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_both_parsers_read_a_file_alike(path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    fast = _read(path)
    monkeypatch.setattr(loader, "_FAST_LOADER", None)
    assert fast == _read(path)


@pytest.mark.parametrize(
    "text",
    [
        "machine: m\nvariables: [\n",  # unclosed flow sequence
        "machine: m\n  bad: indent\n",
        "a: 1\na: 2\n",  # duplicate key: found by the builder, after either parser
        "machine: '\x07'\n",  # a control character
        "key: [a, b\nother: 1\n",
    ],
)
def test_broken_documents_are_reported_as_pyyaml_reports_them(
    text: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "broken.yaml"
    path.write_text(text, encoding="utf-8")
    fast = _read(path)
    monkeypatch.setattr(loader, "_FAST_LOADER", None)
    assert fast == _read(path)

"""Every broken gateway file in tests/corpus/gateway gets the located errors its header promises.

The same `# expect: LINE KEY | MESSAGE-FRAGMENT` headers as tests/corpus/mappings (test_corpus.py).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from gateway.config.loader import load
from gateway.errors import ConfigError
from tests.unit.config.test_corpus import expectations

CORPUS = Path(__file__).resolve().parents[2] / "corpus" / "gateway"
CASES = sorted(CORPUS.glob("*.yaml"))


def test_corpus_is_not_empty() -> None:
    assert CASES
    for path in CASES:
        assert expectations(path), f"{path.name} has no '# expect:' header"


@pytest.mark.parametrize("path", CASES, ids=[p.stem for p in CASES])
def test_broken_gateway_file_reports_every_error_located(path: Path) -> None:
    with pytest.raises(ConfigError) as info:
        load([path], environ={})
    issues = info.value.issues
    for line, key, fragment in expectations(path):
        matching = [i for i in issues if i.line == line and i.key == key and fragment in i.message]
        assert matching, f"expected {path.name}:{line}: {key}: …{fragment}…, got:\n{info.value}"
        assert all(i.file == str(path) for i in matching)
    assert "hunter2" not in str(info.value)  # a password in a URL never reaches the message

"""Every broken mapping file in tests/corpus/mappings gets the located errors its header promises.

Each corpus file starts with `# expect: LINE KEY | MESSAGE-FRAGMENT` comments. All of
them must be reported in one ConfigError (not only the first), each naming the
file, the line and the key.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from gateway.config.loader import load_mapping
from gateway.errors import ConfigError

CORPUS = Path(__file__).resolve().parents[2] / "corpus" / "mappings"
EXPECT = re.compile(r"^# expect: (\d+)\s*([^|]*?)\s*\|\s*(.+)$")


def expectations(path: Path) -> list[tuple[int, str, str]]:
    out = []
    for line in path.read_text(encoding="utf-8").splitlines():
        m = EXPECT.match(line)
        if m:
            out.append((int(m.group(1)), m.group(2), m.group(3)))
    return out


CASES = sorted(CORPUS.glob("*.yaml"))


def test_corpus_is_not_empty() -> None:
    assert len(CASES) >= 15
    for path in CASES:
        assert expectations(path), f"{path.name} has no '# expect:' header"


@pytest.mark.parametrize("path", CASES, ids=[p.stem for p in CASES])
def test_broken_mapping_reports_every_error_located(path: Path) -> None:
    with pytest.raises(ConfigError) as info:
        load_mapping(path, environ={})
    issues = info.value.issues
    for line, key, fragment in expectations(path):
        matching = [i for i in issues if i.line == line and i.key == key and fragment in i.message]
        assert matching, f"expected {path.name}:{line}: {key}: …{fragment}…, got:\n{info.value}"
        assert all(i.file == str(path) for i in matching)


def test_check_command_exits_nonzero_and_prints_every_error() -> None:
    path = CORPUS / "many-errors.yaml"
    proc = subprocess.run(
        [sys.executable, "-m", "gateway.cli.main", "check", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert proc.returncode == 2
    for line, key, _ in expectations(path):
        assert f"{path}:{line}: {key}:" in proc.stderr
    assert "nothing was started" in proc.stderr

"""Every broken fleet file in tests/corpus/fleet (`cnc-gateway fleet`) gets the located error its header
promises (`# expect: LINE KEY | MESSAGE-FRAGMENT`, as tests/corpus/mappings); a good one makes a shard
process per shard, each with its CNC_SHARD, state directory and ports."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from gateway.config.fleet import load_fleet, shard_specs
from gateway.errors import ConfigError
from tests.unit.config.test_corpus import expectations

CORPUS = Path(__file__).resolve().parents[2] / "corpus" / "fleet"
CASES = sorted(CORPUS.glob("*.yaml"))


@pytest.mark.parametrize("path", CASES, ids=[p.stem for p in CASES])
def test_a_broken_fleet_file_is_refused_with_file_line_and_key(path: Path) -> None:
    assert expectations(path), f"{path.name} has no '# expect:' header"
    with pytest.raises(ConfigError) as info:
        load_fleet(path)
    for line, key, fragment in expectations(path):
        matching = [i for i in info.value.issues if i.line == line and i.key == key and fragment in i.message]
        assert matching, f"expected {path.name}:{line}: {key}: …{fragment}…, got:\n{info.value}"


def test_each_shard_gets_its_number_state_directory_and_ports(tmp_path: Path) -> None:
    path = tmp_path / "fleet.yaml"
    path.write_text(
        "gateway: gw.yaml\nshards: 3\nports: {HTTP_PORT: 8080, OPCUA_PORT: 4840}\nstate_dir: st\n"
    )
    fleet, gateway = load_fleet(path)
    specs = shard_specs(fleet, path, gateway)
    assert gateway == (tmp_path / "gw.yaml").resolve()
    assert [s.environ["CNC_SHARD"] for s in specs] == ["1/3", "2/3", "3/3"]
    assert [s.environ["HTTP_PORT"] for s in specs] == ["8080", "8081", "8082"]
    assert [s.environ["OPCUA_PORT"] for s in specs] == ["4840", "4841", "4842"]
    assert [Path(s.environ["CNC_STATE_DIR"]) for s in specs] == [(tmp_path / "st" / f"shard-{k}").resolve()
                                                                 for k in (1, 2, 3)]  # fmt: skip
    assert all(s.command[:4] == [sys.executable, "-m", "gateway.cli.main", "run"] for s in specs)

"""Every file shipped in mappings/ loads, and the committed JSON Schemas are current."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from gateway.auth.passwords import hash_password
from gateway.cli.schema import schema
from gateway.config.loader import is_gateway_file, load, load_mapping, read_yaml

MAPPINGS = Path(__file__).resolve().parents[3] / "mappings"
# compose-fleet/: its machines' files are written by the simulator into the compose fleet's volume;
# tests/unit/config/test_compose_fleet.py loads it over such files.
YAML_FILES = sorted(p for p in MAPPINGS.rglob("*.yaml") if p.parent.name != "compose-fleet")


def test_there_are_mapping_files() -> None:
    assert any(p.name == "laser-sim.yaml" for p in YAML_FILES)


# The secrets the example gateway file takes from the environment (it carries none itself).
ENVIRON = {
    "CNC_OPERATOR_PASSWORD_HASH": hash_password("olga-2024-winter", n=2**10),
    "CNC_INBOX_PASSWORD": "n3st",
}


@pytest.mark.parametrize("path", YAML_FILES, ids=[str(p.relative_to(MAPPINGS)) for p in YAML_FILES])
def test_shipped_file_is_valid(path: Path) -> None:
    config = load([path], environ=ENVIRON)
    assert config.machines
    if not is_gateway_file(read_yaml(path, environ=ENVIRON)):
        assert load_mapping(path, environ={}).machine == config.machines[0].machine


@pytest.mark.parametrize(("name", "gateway"), [("mapping.schema.json", False), ("gateway.schema.json", True)])
def test_committed_schema_matches_the_models(name: str, gateway: bool) -> None:
    committed = json.loads((MAPPINGS / name).read_text(encoding="utf-8"))
    assert committed == schema(gateway), f"mappings/{name} is stale: run `make schema`"


def test_schema_rejects_unknown_keys_like_the_loader() -> None:
    s = schema()
    assert s["additionalProperties"] is False
    assert s["$defs"]["VariableSpec"]["additionalProperties"] is False
    assert "Double[]" in s["$defs"]["VariableSpec"]["properties"]["type"]["enum"]

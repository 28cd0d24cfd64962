"""The simulator's variable table must serve exactly what mappings/laser-sim.yaml reads."""

from __future__ import annotations

from pathlib import Path

import yaml

from simulator.machine import Machine
from simulator.store import MemoryStore
from simulator.variables import GLOBAL_FOLDER, TASKS_FOLDER, Variable, build_variables

ROOT = Path(__file__).resolve().parents[3]


def mapping_variables() -> dict[str, dict[str, object]]:
    doc = yaml.safe_load((ROOT / "mappings" / "laser-sim.yaml").read_text())
    out = {}
    for var in doc["variables"]:
        source = var["source"]
        assert source.startswith("ns=2;s="), source
        out[source.removeprefix("ns=2;s=")] = var
    return out


def test_every_mapped_variable_is_served_with_its_type_and_access() -> None:
    served = {v.node_id: v for v in build_variables()}
    for node_id, var in mapping_variables().items():
        assert node_id in served, f"{node_id} missing from the simulator"
        assert served[node_id].type == var["type"], node_id
        assert served[node_id].writable == (var.get("access") == "readwrite"), node_id


def test_only_the_mapped_writables_and_the_test_hook_are_writable() -> None:
    mapped = {k for k, v in mapping_variables().items() if v.get("access") == "readwrite"}
    writable = {v.node_id for v in build_variables() if v.writable}
    assert writable == mapped | {"::AsGlobalPV:gSim.IgnoreStart"}


def test_node_ids_are_unique_and_values_have_their_types() -> None:
    variables = build_variables()
    assert len({v.node_id for v in variables}) == len(variables)
    m = Machine(MemoryStore())
    python = {
        "Double": float,
        "Float": float,
        "Boolean": bool,
        "String": str,
        "Int16": int,
        "UInt16": int,
        "UInt32": int,
    }
    for v in variables:
        value = v.read(m)
        if v.type.endswith("[]"):
            assert isinstance(value, list), v.node_id
            assert all(isinstance(x, python[v.type[:-2]]) for x in value), v.node_id
        else:
            assert type(value) is python[v.type], v.node_id


def test_browse_tree_is_b_and_r_like() -> None:
    var = Variable("::AsGlobalPV:gAxis[1].ActPos", "Double", lambda m: 0.0)
    assert var.name == "ActPos"
    assert var.ancestors == (
        (GLOBAL_FOLDER, "Global"),
        ("::AsGlobalPV:gAxis", "gAxis"),
        ("::AsGlobalPV:gAxis[1]", "gAxis[1]"),
    )
    local = Variable("::Laser:headTemp", "Float", lambda m: 0.0)
    assert local.ancestors == ((TASKS_FOLDER, "Tasks"), ("::Laser", "Laser"))


def test_command_writes_trigger_on_true_only() -> None:
    m = Machine(MemoryStore({"a.nc": "G4 P1\nM30\n"}))
    by_id = {v.node_id: v for v in build_variables()}
    by_id["::AsGlobalPV:gCmd.SelectProgram"].write(m, "a.nc")  # type: ignore[misc]
    by_id["::AsGlobalPV:gCmd.Start"].write(m, False)  # type: ignore[misc]
    assert m.state == 0
    by_id["::AsGlobalPV:gCmd.Start"].write(m, True)  # type: ignore[misc]
    assert by_id["::AsGlobalPV:gMachine.State"].read(m) == 1
    assert by_id["::AsGlobalPV:gMachine.StateText"].read(m) == "Running"
    assert by_id["::AsGlobalPV:gCmd.Start"].read(m) is False

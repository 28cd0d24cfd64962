"""The seams of sinks and sources: who may import whom (until import-linter contracts enforce the layers).

Imports are read from the source, lazy ones inside functions and those under TYPE_CHECKING included.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def imported(module: str) -> set[str]:
    """Every gateway module `module` imports, anywhere in its source."""
    path = ROOT / (module.replace(".", "/") + ".py")
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return {n for n in names if n.startswith("gateway")}


@pytest.mark.parametrize("transport", ["tcp", "udp", "win32"])
def test_copydata_transports_know_the_port_not_the_emitter(transport: str) -> None:
    names = imported(f"gateway.sinks.copydata.{transport}")
    assert "gateway.sinks.copydata.port" in names
    assert not names & {"gateway.sinks.copydata.emitter", "gateway.sinks.copydata.sink"}
    assert not {
        n
        for n in names
        if n.startswith("gateway.sinks.copydata.")
        and n.split(".")[3] in {"tcp", "udp", "win32"} - {transport}
    }  # nor each other (socket wording: socket_errors.py)


def test_the_copydata_emitter_imports_no_transport() -> None:
    names = imported("gateway.sinks.copydata.emitter")
    assert not {n for n in names if n.split(".")[-1] in {"tcp", "udp", "win32", "sink"}}


def test_the_opcua_server_does_not_import_its_alarms_and_they_do_not_import_it() -> None:
    assert not {n for n in imported("gateway.sinks.opcua.server") if "alarms" in n}
    alarms = imported("gateway.sinks.opcua.alarms")
    assert "gateway.sinks.opcua.port" in alarms and "gateway.sinks.opcua.server" not in alarms


@pytest.mark.parametrize(
    "module", ["gateway.sources.opcua.client", "gateway.sinks.mqtt_link.link", "gateway.sinks.copydata.tcp",
               "gateway.sinks.copydata.udp", "gateway.sinks.copydata.win32"],
)  # fmt: skip
def test_reconnect_loops_use_the_one_helper(module: str) -> None:
    assert "gateway.reconnect" in imported(module)


@pytest.mark.parametrize("module", ["gateway.audit.store", "gateway.sinks.mqtt_link.buffer"])
def test_sqlite_files_are_opened_through_sqlite_file(module: str) -> None:
    source = (ROOT / (module.replace(".", "/") + ".py")).read_text()
    assert "gateway.sqlite_file" in imported(module) and "sqlite3.connect" not in source

"""The driver registry: what a spec must be, the order users see, and drivers from other packages."""

from __future__ import annotations

import typing
from importlib.metadata import EntryPoint
from pathlib import Path

import grimp
import pytest

from gateway import plugins
from gateway.config.mapping import MachineMapping
from gateway.sources import registry
from gateway.sources.base import DriverSpec
from gateway.sources.opcua import SPEC as OPCUA

ROOT = Path(__file__).resolve().parents[3]


@pytest.mark.parametrize("spec", registry.BUILT_IN, ids=lambda s: s.type)
def test_each_driver_model_is_tagged_with_its_type(spec: DriverSpec) -> None:
    annotation = spec.settings.model_fields["type"].annotation
    assert typing.get_origin(annotation) is typing.Literal and typing.get_args(annotation) == (spec.type,)
    assert spec.summary and spec.create is not None


def test_the_default_driver_comes_first_then_by_type() -> None:
    assert registry.types() == ("opcua", "focas", "haas-mdc", "modbus", "mtconnect", "s7", "shdr")
    assert registry.find("opcua") is OPCUA and registry.find("modbus-typo") is None


def test_a_driver_section_without_type_is_the_default_driver() -> None:
    mapping = MachineMapping.model_validate(
        {
            "machine": "m",
            "driver": {"endpoint": "opc.tcp://h:4840"},
            "variables": [{"path": "A", "source": "ns=2;s=A", "type": "Double"}],
        }
    )
    assert mapping.driver.type == "opcua"


def _installed(monkeypatch: pytest.MonkeyPatch, name: str, value: str) -> tuple[DriverSpec, ...]:
    found = [EntryPoint(name=name, value=value, group=registry.GROUP)]
    monkeypatch.setattr(plugins, "entry_points", lambda group: found)
    return plugins.installed(registry.GROUP, DriverSpec, registry.BUILT_IN, lambda spec: spec.type)


def test_an_installed_driver_may_not_take_a_type_already_taken(monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(TypeError, match="'opcua' is already cnc-gateway's"):
        _installed(monkeypatch, "mine", "gateway.sources.opcua:SPEC")


def test_an_installed_driver_must_be_a_driver_spec(monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(
        TypeError, match=r"entry point x = gateway.sources.registry:GROUP \(cnc_gateway.drivers\) is"
    ):
        _installed(monkeypatch, "x", "gateway.sources.registry:GROUP")


def test_driver_folders_import_no_other_driver_and_nothing_of_the_configuration_files() -> None:
    """A driver reads its mapping through DriverMapping (gateway/sources/base.py), and each folder stands
    alone, so that a driver can be added or removed as one folder."""
    graph = grimp.build_graph("gateway")
    folders = {s.create.__module__ for s in registry.BUILT_IN}
    assert folders == {
        "gateway.sources.opcua",
        "gateway.sources.mtconnect",
        "gateway.sources.focas",
        "gateway.sources.haas_mdc",
        "gateway.sources.modbus",
        "gateway.sources.s7",
    }
    for folder in folders:
        modules = {folder} | graph.find_descendants(folder)
        imported = set().union(*(graph.find_modules_directly_imported_by(m) for m in modules))
        others = {m for m in imported for f in folders - {folder} if m == f or m.startswith(f + ".")}
        assert not others, f"{folder} imports {others}"
        assert not {m for m in imported if m.startswith("gateway.config")}, folder

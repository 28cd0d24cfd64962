"""The delivery transport registry: what a spec must be, the `jobs.controller` union built from it, and
transports from other packages."""

from __future__ import annotations

import typing
from importlib.metadata import EntryPoint
from pathlib import Path

import grimp
import pytest

from gateway import plugins
from gateway.config.jobs import JobsConfig
from gateway.errors import ConfigError
from gateway.transports import registry
from gateway.transports.base import TransportSpec
from gateway.transports.dnc.config import ControllerSerial
from gateway.transports.focas.config import ControllerFocas
from gateway.transports.ftp import SPEC as FTP
from gateway.transports.ftp.config import ControllerFtp


@pytest.mark.parametrize("spec", registry.BUILT_IN, ids=lambda s: s.type)
def test_each_transport_model_is_tagged_with_its_type(spec: TransportSpec) -> None:
    annotation = spec.settings.model_fields["type"].annotation
    assert typing.get_origin(annotation) is typing.Literal and typing.get_args(annotation) == (spec.type,)
    assert spec.summary and spec.assemble is not None


def test_the_transports_in_the_order_the_schema_lists_them() -> None:
    assert registry.types() == ("ftp", "serial", "focas")
    assert registry.find("ftp") is FTP and registry.DEFAULT == "ftp"
    with pytest.raises(TypeError, match="no delivery transport of type 'ftp-typo'"):
        registry.find("ftp-typo")


@pytest.mark.parametrize(
    ("controller", "model"),
    [
        ({"host": "10.0.0.5"}, ControllerFtp),  # files from before serial DNC: no type
        ({"type": "ftp", "host": "10.0.0.5"}, ControllerFtp),
        ({"type": "serial", "where": "/dev/ttyUSB0"}, ControllerSerial),
        ({"type": "focas", "host": "10.0.0.6"}, ControllerFocas),
    ],
)
def test_the_controller_union_is_the_registry_s_models(controller: dict[str, str], model: type) -> None:
    assert type(JobsConfig.model_validate({"controller": controller}).controller) is model


def test_only_transports_with_a_store_open_one() -> None:
    assert registry.program_store_for(ControllerFtp(host="h")) is not None
    assert registry.program_store_for(ControllerFocas(type="focas", host="h")) is not None
    assert registry.program_store_for(ControllerSerial(type="serial", where="/dev/ttyS0")) is None


def test_an_unknown_controller_type_is_an_error_naming_file_line_and_key(tmp_path: Path) -> None:
    from gateway.config.loader import load_mapping

    path = tmp_path / "m.yaml"
    path.write_text(
        "machine: m\n"
        "driver: {endpoint: 'opc.tcp://h:4840'}\n"
        "variables: [{path: A, source: 'ns=2;s=A', type: Double}]\n"
        "jobs:\n"
        "  controller: {type: punchcard, host: h}\n"
    )
    with pytest.raises(ConfigError) as caught:
        load_mapping(path)
    text = str(caught.value)
    assert f"{path}:5" in text and "jobs.controller" in text


def _installed(monkeypatch: pytest.MonkeyPatch, name: str, value: str) -> tuple[TransportSpec, ...]:
    found = [EntryPoint(name=name, value=value, group=registry.GROUP)]
    monkeypatch.setattr(plugins, "entry_points", lambda group: found)
    return plugins.installed(registry.GROUP, TransportSpec, registry.BUILT_IN, lambda spec: spec.type)


def test_an_installed_transport_may_not_take_a_type_already_taken(monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(TypeError, match="'serial' is already cnc-gateway's"):
        _installed(monkeypatch, "mine", "gateway.transports.dnc:SPEC")


def test_an_installed_transport_must_be_a_transport_spec(monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(
        TypeError, match=r"entry point x = gateway.transports.registry:GROUP \(cnc_gateway.transports\) is"
    ):
        _installed(monkeypatch, "x", "gateway.transports.registry:GROUP")


def test_transport_folders_import_no_other_transport_and_nothing_of_the_jobs_or_the_configuration() -> None:
    """A transport knows the core through the ports of gateway/transports/base.py, and each folder stands
    alone, so that a transport is added or removed as its folder and its registry line."""
    graph = grimp.build_graph("gateway")
    folders = {s.assemble.__module__ for s in registry.BUILT_IN}
    assert folders == {"gateway.transports.ftp", "gateway.transports.dnc", "gateway.transports.focas"}
    for folder in folders:
        modules = {folder} | graph.find_descendants(folder)
        imported = set().union(*(graph.find_modules_directly_imported_by(m) for m in modules))
        others = {m for m in imported for f in folders - {folder} if m == f or m.startswith(f + ".")}
        assert not others, f"{folder} imports {others}"
        assert not {m for m in imported if m.startswith(("gateway.config", "gateway.jobs"))}, folder

"""The no_module_cycles contract (tests/import_contracts.py) on small graphs: it finds what it must."""

from __future__ import annotations

import grimp

from tests.import_contracts import cycles, module_edges


def graph(*imports: tuple[str, str, str]) -> grimp.ImportGraph:
    g = grimp.ImportGraph()
    for importer, imported, text in imports:
        for module in (importer, imported):
            g.add_module(module)
        g.add_import(importer=importer, imported=imported, line_number=1, line_contents=text)
    return g


def found(g: grimp.ImportGraph) -> list[list[tuple[str, str]]]:
    return [[(e.importer, e.imported) for e in cycle] for cycle in cycles(module_edges(g, {"pkg"}))]


def test_a_package_init_and_its_module_that_imports_from_the_package() -> None:
    g = graph(
        ("pkg.cli", "pkg.cli.main", "from pkg.cli.main import main"),
        ("pkg.cli.main", "pkg.cli.alarms", "from pkg.cli import alarms"),  # runs pkg/cli/__init__.py first
    )
    assert found(g) == [[("pkg.cli", "pkg.cli.main"), ("pkg.cli.main", "pkg.cli")]]


def test_a_cycle_hidden_in_a_function_or_under_type_checking() -> None:
    g = graph(
        ("pkg.model.tree", "pkg.model.hub", "from pkg.model.hub import ChangeHub"),
        ("pkg.model.hub", "pkg.model.status", "from pkg.model.status import Status"),
        ("pkg.model.status", "pkg.model.tree", "from pkg.model.tree import Machine"),  # TYPE_CHECKING only
        ("pkg.sinks.emitter", "pkg.sinks.tcp", "from pkg.sinks import tcp"),  # inside a function
        ("pkg.sinks.tcp", "pkg.sinks.emitter", "from pkg.sinks.emitter import Emitter"),
    )
    assert found(g) == [
        [("pkg.model.hub", "pkg.model.status"), ("pkg.model.status", "pkg.model.tree"),
         ("pkg.model.tree", "pkg.model.hub")],
        [("pkg.sinks.emitter", "pkg.sinks.tcp"), ("pkg.sinks.tcp", "pkg.sinks.emitter")],
    ]  # fmt: skip


def test_layers_without_a_way_back_are_no_cycle() -> None:
    g = graph(
        ("pkg.cli.main", "pkg.cli.alarms", "from pkg.cli import alarms"),  # the package's __init__ is empty
        ("pkg.app", "pkg.model.tree", "from pkg.model.tree import VariableTree"),
        ("pkg.model.tree", "pkg.errors", "from pkg.errors import WriteError"),
        ("other.x", "pkg.app", "import pkg.app"),  # outside the containers
    )
    assert found(g) == []


def test_every_part_of_gateway_has_its_layer() -> None:
    """A new package or top-level module of gateway/ goes into the layers contract (pyproject.toml)."""
    import pkgutil
    import tomllib
    from pathlib import Path

    import gateway

    root = Path(__file__).resolve().parents[2]
    config = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["importlinter"]
    (layers,) = [c["layers"] for c in config["contracts"] if c["type"] == "layers"]
    named = {name.strip(" ()") for line in layers for name in line.replace(":", "|").split("|")}
    parts = {f"gateway.{m.name}" for m in pkgutil.iter_modules(gateway.__path__)}
    assert parts - named == set(), "add these to the layers contract in pyproject.toml"
    assert named - parts == set(), "the layers contract names parts that do not exist"

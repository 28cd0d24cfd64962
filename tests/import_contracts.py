"""An import-linter contract type: no import cycle between modules (pyproject.toml, `no_module_cycles`).

import-linter's own `acyclic_siblings` finds cycles between the children of each package, at every
depth, which covers package cycles and module cycles across packages. Two kinds of cycle escape it:

- a package's `__init__` and one of its own modules (`gateway/cli/__init__.py` importing
  `gateway.cli.main`, which imports `gateway.cli`), because a package is not a sibling of its children;
- `from gateway.cli import alarms`: grimp records it as an import of `gateway.cli.alarms` only, yet
  Python runs `gateway/cli/__init__.py` first, so the importer depends on the package too.

This contract takes grimp's graph of the `containers` (which includes imports under TYPE_CHECKING and
imports inside functions: the project's configuration keeps both), adds an edge to the package for every
`from <package> import ...`, and fails on every strongly connected set of modules, printing a shortest
cycle through it with the import lines. tests/unit/test_import_contracts.py shows it failing.
"""

from __future__ import annotations

import re
from collections import deque
from dataclasses import dataclass

import grimp
from importlinter.application import output
from importlinter.domain import fields
from importlinter.domain.contract import Contract, ContractCheck

_FROM_IMPORT = re.compile(r"^\s*from\s+([\w.]+)\s+import\b")


@dataclass(frozen=True)
class Edge:
    importer: str
    imported: str
    line: int
    text: str


def module_edges(graph: grimp.ImportGraph, containers: set[str]) -> dict[str, dict[str, Edge]]:
    """importer -> imported -> one import that makes the edge, for the modules inside `containers`."""

    def inside(module: str) -> bool:
        return any(module == c or module.startswith(c + ".") for c in containers)

    modules = {m for m in graph.modules if inside(m)}
    packages = {m for m in modules if graph.find_children(m)}
    edges: dict[str, dict[str, Edge]] = {m: {} for m in modules}
    for importer in modules:
        for imported in graph.find_modules_directly_imported_by(importer):
            if imported not in modules:
                continue
            for detail in graph.get_import_details(importer=importer, imported=imported):
                line, text = detail["line_number"], detail["line_contents"].strip()
                edges[importer].setdefault(imported, Edge(importer, imported, line, text))
                match = _FROM_IMPORT.match(text)
                package = match.group(1) if match else None
                if package in packages and package not in (importer, imported):
                    edges[importer].setdefault(package, Edge(importer, package, line, text))
            if imported not in edges[importer]:  # an import grimp gives no details for
                edges[importer][imported] = Edge(importer, imported, 0, "")
    return edges


def cycles(edges: dict[str, dict[str, Edge]]) -> list[list[Edge]]:
    """One shortest cycle (as its edges) per strongly connected set of two or more modules."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[set[str]] = []
    for root in sorted(edges):
        if root in index:
            continue
        work = [(root, iter(sorted(edges[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(edges[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = set()
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.add(member)
                    if member == node:
                        break
                if len(component) > 1:
                    components.append(component)
    return [_shortest_cycle(edges, component) for component in sorted(components, key=min)]


def _shortest_cycle(edges: dict[str, dict[str, Edge]], component: set[str]) -> list[Edge]:
    start = min(component)
    came: dict[str, Edge] = {}
    queue = deque([start])
    while queue:
        node = queue.popleft()
        for target, edge in sorted(edges[node].items()):
            if target not in component:
                continue
            if target == start:
                path = [edge]
                while path[0].importer != start:
                    path.insert(0, came[path[0].importer])
                return path
            if target not in came:
                came[target] = edge
                queue.append(target)
    raise AssertionError(f"no cycle through {start}")  # pragma: no cover - a component has one


class NoModuleCyclesContract(Contract):
    """No module of `containers` reaches itself by imports (see the module docstring)."""

    type_name = "no_module_cycles"

    containers = fields.SetField(subfield=fields.StringField())

    def check(self, graph: grimp.ImportGraph, verbose: bool) -> ContractCheck:
        found = cycles(module_edges(graph, set(self.containers)))
        return ContractCheck(kept=not found, metadata={"cycles": found})

    def render_broken_contract(self, check: ContractCheck) -> None:
        for cycle in check.metadata["cycles"]:
            output.print_error(f"Import cycle through {len(cycle)} modules:", bold=True)
            for edge in cycle:
                where = f"l.{edge.line}: {edge.text}" if edge.line else "an import"
                output.print_error(f"  {edge.importer} -> {edge.imported} ({where})", bold=False)
            output.new_line()

"""The adapters table of docs/architecture.md, generated from the registries.

`python -m tests.architecture_doc --write` rewrites the table between its markers;
tests/unit/test_architecture_doc.py fails when the document and the registries disagree, so the table
cannot drift from the code.
"""

from __future__ import annotations

import sys
from pathlib import Path

from gateway.sinks.opcua.extensions import BUILT_IN as EXTENSIONS
from gateway.sinks.registry import BUILT_IN as SINKS
from gateway.sinks.registry import WEB
from gateway.sources.registry import BUILT_IN as DRIVERS
from gateway.transports.registry import BUILT_IN as TRANSPORTS

DOC = Path(__file__).resolve().parents[1] / "docs" / "architecture.md"
BEGIN = "<!-- adapters: generated from the registries by tests/architecture_doc.py; do not edit by hand -->"
END = "<!-- adapters: end -->"


def _folder(module: str) -> str:
    """The adapter's folder: where the module of its factory lives."""
    file = sys.modules[module].__file__
    assert file is not None
    return f"{Path(file).resolve().parent.relative_to(DOC.parents[1])}/"


def rows() -> list[tuple[str, str, str, str]]:
    """(kind, name, folder, summary) of every built-in adapter, in the registries' order."""
    out: list[tuple[str, str, str, str]] = []
    for driver in DRIVERS:
        out.append(("driver", f"`{driver.type}`", _folder(driver.create.__module__), driver.summary))
    for sink in (*SINKS, WEB):
        out.append(("sink", f"`{sink.name}`", _folder(sink.create.__module__), sink.summary))
    for ext in EXTENSIONS:
        out.append(("OPC UA extension", f"`{ext.name}`", _folder(ext.create.__module__), ext.summary))
    for transport in TRANSPORTS:
        folder = _folder(transport.assemble.__module__)
        out.append(("delivery transport", f"`{transport.type}`", folder, transport.summary))
    return out


def table() -> str:
    lines = ["| kind | name | folder | what it is |", "|---|---|---|---|"]
    lines += [f"| {kind} | {name} | `{folder}` | {summary} |" for kind, name, folder, summary in rows()]
    return "\n".join(lines)


def expected(document: str) -> str:
    """The document with its generated table as the registries say it should be."""
    head, rest = document.split(BEGIN, 1)
    _old, tail = rest.split(END, 1)
    return f"{head}{BEGIN}\n{table()}\n{END}{tail}"


if __name__ == "__main__":
    text = DOC.read_text()
    if "--write" in sys.argv[1:]:
        DOC.write_text(expected(text))
    else:
        print(table())

"""An example OPC UA server extension (a "view"), as small as one can be: per machine with an
`example_view:` section in its mapping, a `Note` variable under the machine's object, holding the note.

It shows an extension's whole contract: its mapping key (a Section: model, description, a check against
the machine's variables that gives file:line errors, the lines `cnc-gateway check` prints), its factory
(an ExtensionContext in, a ServerExtension out) and the server seen only through ServerPort
(install.py). Like tests/example_driver it plugs in through an entry point
(`cnc_gateway.opcua_extensions`); one inside the tree is a folder gateway/sinks/opcua/<name>/ and its
line in gateway/sinks/opcua/extensions.py. tests/integration/test_example_view.py runs it.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import TYPE_CHECKING, Any

from pydantic import Field

from gateway.settings.base import Strict
from gateway.settings.sections import Loc, Section
from gateway.sinks.opcua.extensions import ExtensionContext, ExtensionSpec

if TYPE_CHECKING:
    from gateway.sinks.opcua.port import ServerExtension


class ExampleView(Strict):
    """An example view: a note per machine, and the variable it is about."""

    note: str = Field(min_length=1, description="The text of the machine's Note variable")
    about: str = Field(description="A variable of this mapping the note is about")


def _check(view: ExampleView, earlier: Mapping[str, Any]) -> Iterable[tuple[Loc, str]]:
    """`earlier`: the mapping's keys validated before this one (variables, jobs, alarms ...)."""
    if view.about not in {v.path for v in earlier.get("variables", ())}:
        yield ("about",), f"{view.about!r} is not a variable of this mapping"


def _report(view: ExampleView) -> Iterable[str]:
    yield f"example view: Note {view.note!r} about {view.about}"


SECTION = Section(
    "example_view",
    ExampleView,
    "An example view: a Note variable under the machine's object",
    check=_check,
    report=_report,
)


def _create(context: ExtensionContext) -> ServerExtension | None:
    if not context.machines:  # no machine has the section: nothing to install
        return None
    from cnc_example_view.install import NoteView

    return NoteView(context.machines)


SPEC = ExtensionSpec(
    name="example-view",
    summary="an example view: a Note variable per machine",
    create=_create,
    machine_section=SECTION,
)

"""Keys an adapter adds to a configuration file, and the models that carry them.

An adapter that needs a key of its own (`umati:` per machine in the mapping file, a new sink's section
in the gateway file, a key under `opcua:`) declares a `Section` in its spec; the model of that file
appends every registered section (`with_sections`), so that the schema, the located errors
(`file:line: umati.model: ...`) and the loaded values include it without an edit of gateway/config/.
Keys the models already declare (the sections of the adapters that came before the registry) are left
as they are.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, ClassVar, TypeVar

from pydantic import BaseModel, Field, ValidationError, ValidationInfo, create_model, field_validator
from pydantic_core import InitErrorDetails, PydanticCustomError

from gateway.settings.base import Strict

Loc = tuple[str | int, ...]
S = TypeVar("S", bound="Sectioned")


@dataclass(frozen=True)
class Section:
    """One key of a configuration file that an adapter owns."""

    key: str
    model: type[BaseModel]  # its model (a Strict model of the adapter's config.py)
    # The schema's description of the key; "" for keys the file's model declares itself (the sections of
    # the adapters that came before the registry: their fields say it).
    description: str = ""
    # Cross-checks of the section against the rest of its file: called with the section's value and the
    # file's keys validated before it, by key (in a mapping file `variables` (VariableSpecs: .path, .type,
    # .writable ...), `jobs`, `alarms`, `commands` ...; a key that failed validation is absent), it
    # yields (location inside the section, message), each a `file:line: <key>.<location>: message`.
    check: Callable[[Any, Mapping[str, Any]], Iterable[tuple[Loc, str]]] | None = None
    # Lines `cnc-gateway check` prints under a machine whose mapping has the section.
    report: Callable[[Any], Iterable[str]] | None = None


class Sectioned(Strict):
    """A model that registered sections may extend (the mapping file, the gateway file, `opcua:`)."""

    sections: ClassVar[tuple[Section, ...]] = ()

    def section(self, section: Section) -> BaseModel | None:
        """The value of a registered section (None when the file does not have the key)."""
        value = self.__dict__.get(section.key)
        return value if isinstance(value, section.model) else None


def with_sections(model: type[S], sections: Iterable[Section]) -> type[S]:
    """`model` with one optional key per section it does not declare yet, validated by the section's
    model and checked by its `check` (which sees the keys validated before it). The model itself
    when there is none, so that a gateway without such adapters runs the models as written."""
    new: dict[str, Section] = {}
    for section in sections:
        if section.key in model.model_fields:
            continue
        if section.key in new:
            raise TypeError(f"two adapters claim the key {section.key!r} of {model.__name__}")
        new[section.key] = section
    if not new:
        return model
    fields: dict[str, Any] = {
        key: (section.model | None, Field(default=None, description=section.description))
        for key, section in new.items()
    }
    validators = {
        f"_check_{key}": field_validator(key)(_checker(section))
        for key, section in new.items()
        if section.check is not None
    }
    extended: type[S] = create_model(
        model.__name__,
        __base__=model,
        __module__=model.__module__,
        __doc__=model.__doc__,
        __validators__=validators,
        **fields,
    )
    extended.sections = (*model.sections, *new.values())
    return extended


def _checker(section: Section) -> Callable[[type[BaseModel], Any, ValidationInfo], Any]:
    def check(cls: type[BaseModel], value: Any, info: ValidationInfo) -> Any:
        if value is not None and section.check is not None:
            located_errors(list(section.check(value, MappingProxyType(info.data))))
        return value

    return check


def located_errors(issues: Sequence[tuple[Loc, str]]) -> None:
    """Raise cross-check issues from a field validator as one ValidationError whose errors sit at their own
    keys (pydantic prefixes the field's location), so that the loader reports file:line:key for each."""
    if not issues:
        return
    raise ValidationError.from_exception_data(
        "MachineMapping",
        [
            InitErrorDetails(
                type=PydanticCustomError("value_error", "{message}", {"message": message}),
                loc=loc,
                input=None,
            )
            for loc, message in issues
        ],
    )

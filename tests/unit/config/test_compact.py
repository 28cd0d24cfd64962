"""gateway/settings/compact.py: a variable's spec in less memory, the same to everything that reads it."""

from __future__ import annotations

import copy
import sys

from hypothesis import given
from hypothesis import strategies as st

from gateway.config.mapping import VariableSpec
from gateway.model.types import TypeSpec
from gateway.settings.compact import SharedFieldNames

UNITS = st.sampled_from(["", "mm", "%"])
TYPES = st.sampled_from(["Double", "UInt16", "String", "Boolean[]"])


@given(
    name=st.from_regex(r"[A-Za-z][A-Za-z0-9_]{0,8}", fullmatch=True),
    type_name=TYPES,
    unit=UNITS,
    writable=st.booleans(),
)
def test_a_compact_spec_reads_dumps_compares_and_copies_as_a_plain_one(
    name: str, type_name: str, unit: str, writable: bool
) -> None:
    data = {"path": f"Axes/{name}", "source": f"ns=2;s={name}", "type": type_name}
    if unit:
        data["unit"] = unit
    if writable:
        data["access"] = "readwrite"
    spec = VariableSpec.model_validate(data)
    assert type(spec.__pydantic_fields_set__) is SharedFieldNames
    assert spec.model_fields_set == set(data)
    assert spec.model_dump() == VariableSpec.model_construct(**spec.model_dump()).model_dump()
    assert spec.path == data["path"] and spec.unit == unit and spec.writable is writable
    assert spec == VariableSpec.model_validate(data)
    changed = spec.model_copy(update={"description": "changed"})
    assert changed.description == "changed" and spec.description == ""
    assert "description" in changed.model_fields_set and "description" not in spec.model_fields_set
    deep = copy.deepcopy(spec)
    assert deep == spec and deep.model_fields_set == spec.model_fields_set


def test_specs_alike_share_their_names_and_take_less_than_a_dict_apiece() -> None:
    specs = [VariableSpec(path=f"V/v{k}", source=f"ns=2;s=v{k}", type="Double") for k in range(3)]
    assert specs[0].__pydantic_fields_set__ is specs[2].__pydantic_fields_set__
    plain = dict(specs[0].__dict__)
    assert sys.getsizeof(specs[1].__dict__) < sys.getsizeof(plain)
    assert specs[0].type is specs[1].type is TypeSpec.parse("Double")  # one TypeSpec per type

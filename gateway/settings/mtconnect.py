"""How a variable appears in MTConnect (`mtconnect:` on a variable), in the standard's own words.

Read by the MTConnect agent sink (its Devices and values) and by the MTConnect drivers (an SHDR
adapter's conditions, messages and time series), so it sits below both.
"""

from __future__ import annotations

import re
from typing import Literal

from pydantic import Field, field_validator

from gateway.settings.base import Strict

_TYPE = re.compile(r"^(?:[a-z][a-z0-9]*:)?[A-Z][A-Z0-9_]*$")
_STEP = re.compile(r"^(?:[a-z][a-z0-9]*:)?[A-Z][A-Za-z0-9]*(?:\[[A-Za-z0-9_.\- ]+\])?$")
_ID = re.compile(r"^[A-Za-z_][A-Za-z0-9_.\-]*$")


Category = Literal["SAMPLE", "EVENT", "CONDITION"]


class VariableMTConnect(Strict):
    """How one variable appears in the MTConnect agent, in the standard's own words."""

    category: Category
    type: str = Field(description="The data item type: POSITION, PATH_FEEDRATE, EXECUTION, SYSTEM, ...")
    sub_type: str | None = Field(default=None, alias="subType", description="ACTUAL, COMMANDED, ...")
    component: str | None = Field(
        default=None,
        description="Where it sits below the Device: steps of ComponentType[name], e.g. Axes/Linear[X] or "
        "Controller/Path; default: on the Device itself",
    )
    name: str | None = Field(default=None, description="The data item's name (default: none)")
    id: str | None = Field(default=None, description="The data item id (default: <machine>.<path>)")
    units: str | None = Field(
        default=None, description="MTConnect units; default: the standard's for the variable's unit"
    )
    native_units: str | None = Field(
        default=None, alias="nativeUnits", description="What the controller uses; default: from `unit`"
    )
    significant_digits: int | None = Field(default=None, alias="significantDigits", ge=0, le=30)
    coordinate_system: Literal["MACHINE", "WORK"] | None = Field(default=None, alias="coordinateSystem")
    discrete: bool = False
    representation: Literal["VALUE", "TIME_SERIES"] = Field(
        default="VALUE", description="TIME_SERIES: a SAMPLE of several readings per observation (Double[])"
    )
    values: dict[str, str] | None = Field(
        default=None,
        description="The variable's values as MTConnect words, e.g. {0: READY, 1: ACTIVE} or {true: ON}",
    )

    @field_validator("type")
    @classmethod
    def _type(cls, value: str) -> str:
        if not _TYPE.match(value):
            raise ValueError(
                f"{value!r} is not an MTConnect type (upper case words joined by _, e.g. POSITION)"
            )
        return value

    @field_validator("sub_type")
    @classmethod
    def _sub_type(cls, value: str | None) -> str | None:
        if value is not None and not _TYPE.match(value):
            raise ValueError(f"{value!r} is not an MTConnect subType (e.g. ACTUAL, COMMANDED)")
        return value

    @field_validator("component")
    @classmethod
    def _component(cls, value: str | None) -> str | None:
        if value is None:
            return None
        for step in value.split("/"):
            if not _STEP.match(step):
                raise ValueError(
                    f"component step {step!r} must be a component type, optionally with a name: Axes, "
                    "Linear[X], Path[path1]"
                )
        return value

    @field_validator("id")
    @classmethod
    def _id(cls, value: str | None) -> str | None:
        if value is not None and not _ID.match(value):
            raise ValueError(f"{value!r} is not an XML id (a letter or _ first; letters, digits, _ . -)")
        return value

    @field_validator("values", mode="before")
    @classmethod
    def _value_keys(cls, value: object) -> object:
        """YAML keys may be numbers or booleans: compare them as the text the sink makes of a value."""
        if isinstance(value, dict):
            return {_written_key(k): v for k, v in value.items()}
        return value


def value_key(value: object) -> str:
    """The text a value is looked up by in `values`: true/false for booleans, 3 for 3.0."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and value.is_integer():
        return str(int(value))
    return str(value)


def _written_key(key: object) -> str:
    """A `values` key as written (the loader hands YAML keys over as text: "True", "0")."""
    if isinstance(key, str):
        if key.lower() in ("true", "false"):
            return key.lower()
        try:
            number = float(key)
        except ValueError:
            return key
        return value_key(number) if number.is_integer() else key
    return value_key(key)

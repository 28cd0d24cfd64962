"""A machine's `alarms:` section: where its active alarms come from, and how severe each class is.

```yaml
alarms:
  source:
    type: arrays                      # parallel arrays of the active alarms, as many PLCs expose them
    ids: ActiveAlarms/Ids             # integer or String array: the alarm numbers
    texts: ActiveAlarms/Texts         # String array (optional): the texts, in the controller's language
    severities: ActiveAlarms/Severities   # integer array (optional): the controller's severity classes
    parameters: {Axis: ActiveAlarms/Axes} # optional: more parallel arrays, one value per alarm
  severity: {1: 100, 2: 400, 3: 700, 4: 900}   # class -> OPC UA severity (1..1000)
  default_severity: 500               # classes not listed, or no severities array
  acknowledge_role: operator          # lowest role that may acknowledge and confirm
  confirm: false                      # true: an alarm stays listed until it is also confirmed
```

`source.type` is the seam for drivers that report alarms their own way (a
subscription to the controller's own alarm events, say): a new member of the
`AlarmSource` union, read by its own class in gateway/alarms/sources.py.
Cross-checks against the mapping's variables (paths exist, types fit) run in
`alarms_issues`, which MachineMapping calls so that each error names its key.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Annotated, Any, Literal

from pydantic import Discriminator, Field, Tag, field_validator

from gateway.settings.access import check_role_name
from gateway.settings.base import Strict

SEVERITY_MIN, SEVERITY_MAX = 1, 1000


class ArraySource(Strict):
    """The active alarms as parallel arrays of mapped variables: entry i of each array is alarm i."""

    type: Literal["arrays"] = "arrays"
    ids: str = Field(description="Array variable with the alarm numbers (integers or text)")
    texts: str | None = Field(default=None, description="String array variable with the alarm texts")
    severities: str | None = Field(
        default=None, description="Integer array variable with the controller's severity classes"
    )
    parameters: dict[str, str] = Field(
        default_factory=dict,
        description="Further parallel arrays, by parameter name: {Axis: ActiveAlarms/Axes}",
    )

    @field_validator("parameters")
    @classmethod
    def _parameter_names(cls, value: dict[str, str]) -> dict[str, str]:
        for name in value:
            if not name or not name.replace("_", "").isalnum():
                raise ValueError(f"parameter name {name!r} must be letters, digits and '_'")
        return value


ConditionLevel = Literal["WARNING", "FAULT"]
DEFAULT_CLASSES: dict[ConditionLevel, int] = {"WARNING": 2, "FAULT": 3}


class ConditionSource(Strict):
    """MTConnect conditions: the active Warnings and Faults of CONDITION variables (an MTConnect driver's).

    Each variable is a String[] of active conditions (gateway/codecs/mtconnect/conditions.py), as
    the MTConnect and SHDR drivers keep them; every Warning or Fault becomes an alarm, with the
    condition's id (or native code) as its id and its level as its severity class.
    """

    type: Literal["conditions"]
    variables: list[str] | None = Field(
        default=None,
        description="The CONDITION variables to follow; default: every variable whose mtconnect "
        "category is CONDITION",
    )
    classes: dict[ConditionLevel, int] = Field(
        default_factory=lambda: dict(DEFAULT_CLASSES),
        description="Severity class of each level (graded by `severity` like a controller's classes)",
    )


def _source_type(value: Any) -> str:
    """Which source model an `alarms.source` section is; files from before `conditions` have no `type`."""
    if isinstance(value, dict):
        return str(value.get("type", "arrays"))
    return str(getattr(value, "type", "arrays"))


SOURCE_TAGS = ("arrays", "conditions")
AlarmSource = Annotated[
    Annotated[ArraySource, Tag("arrays")] | Annotated[ConditionSource, Tag("conditions")],
    Discriminator(_source_type),
]


class AlarmsConfig(Strict):
    """Where a machine's alarms come from and how they are graded (mapping file, `alarms:`)."""

    source: AlarmSource = Field(description="Where the active alarms are read")
    severity: dict[int, int] = Field(
        default_factory=lambda: {1: 100, 2: 400, 3: 700, 4: 900},
        description="Controller severity class -> OPC UA severity (1 lowest .. 1000 highest)",
    )
    default_severity: int = Field(
        default=500,
        ge=SEVERITY_MIN,
        le=SEVERITY_MAX,
        description="Severity of classes the map does not list, "
        "and of every alarm without a severities array",
    )
    acknowledge_role: str = Field(
        default="operator", description="Lowest role that may acknowledge and confirm this machine's alarms"
    )
    confirm: bool = Field(
        default=False,
        description="true: a cleared, acknowledged alarm stays listed (OPC UA Retain) "
        "until it is also confirmed",
    )

    @field_validator("severity")
    @classmethod
    def _severities(cls, value: dict[int, int]) -> dict[int, int]:
        for cls_, sev in value.items():
            if not SEVERITY_MIN <= sev <= SEVERITY_MAX:
                raise ValueError(f"severity of class {cls_} is {sev}; OPC UA severities are 1..1000")
        return value

    @field_validator("acknowledge_role")
    @classmethod
    def _role(cls, value: str) -> str:
        return check_role_name(value)

    def severity_of(self, severity_class: int | None) -> int:
        if severity_class is None:
            return self.default_severity
        return self.severity.get(severity_class, self.default_severity)


def alarms_issues(alarms: AlarmsConfig, variables: Sequence[Any]) -> list[tuple[tuple[str | int, ...], str]]:
    """(location below `alarms`, message) for every source path that is missing or of the wrong type."""
    by_path = {v.path: v for v in variables}
    source = alarms.source
    if isinstance(source, ConditionSource):
        return condition_issues(source, variables)
    wanted: list[tuple[tuple[str | int, ...], str | None, str]] = [
        (("source", "ids"), source.ids, "ids"),
        (("source", "texts"), source.texts, "texts"),
        (("source", "severities"), source.severities, "severities"),
    ]
    wanted += [
        (("source", "parameters", name), path, "parameter") for name, path in source.parameters.items()
    ]
    issues: list[tuple[tuple[str | int, ...], str]] = []
    for loc, path, role in wanted:
        if path is None:
            continue
        var = by_path.get(path)
        if var is None:
            issues.append((loc, f"{path!r} is not a variable of this mapping"))
            continue
        spec = var.type
        if not spec.array:
            issues.append((loc, f"{path} is {spec}; the alarm arrays must be arrays (e.g. UInt32[])"))
        elif role == "ids" and not (spec.is_integer or str(spec) == "String[]"):
            issues.append((loc, f"{path} is {spec}; alarm ids must be an integer or String array"))
        elif role == "texts" and str(spec) != "String[]":
            issues.append((loc, f"{path} is {spec}; alarm texts must be String[]"))
        elif role == "severities" and not spec.is_integer:
            issues.append((loc, f"{path} is {spec}; severity classes must be an integer array"))
    return issues


def condition_variables(source: ConditionSource, variables: Sequence[Any]) -> list[str]:
    """The paths a conditions source follows: the ones it names, else every CONDITION variable."""
    if source.variables is not None:
        return list(source.variables)
    return [v.path for v in variables if v.mtconnect is not None and v.mtconnect.category == "CONDITION"]


def condition_issues(
    source: ConditionSource, variables: Sequence[Any]
) -> list[tuple[tuple[str | int, ...], str]]:
    by_path = {v.path: v for v in variables}
    issues: list[tuple[tuple[str | int, ...], str]] = []
    paths = condition_variables(source, variables)
    if not paths:
        issues.append(
            (("source",), "no CONDITION variable to follow (give mtconnect: {category: CONDITION})")
        )
    for index, path in enumerate(paths):
        loc: tuple[str | int, ...] = (
            ("source", "variables", index) if source.variables is not None else ("source",)
        )
        var = by_path.get(path)
        if var is None:
            issues.append((loc, f"{path!r} is not a variable of this mapping"))
        elif str(var.type) != "String[]":
            issues.append((loc, f"{path} is {var.type}; a condition's active list is String[]"))
    return issues

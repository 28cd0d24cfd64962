"""The mapping file: one machine, its controller, and its variables.

These pydantic models are the single definition of the format. They validate a
file once, at start-up, and also produce the JSON Schema that editors use
(`cnc-gateway schema`). Unknown keys are errors, not silently ignored.

The variable tree does not see these models: `MachineMapping.definition()` turns a
mapping into the model's own frozen definitions (gateway/model/definitions.py).
The components that read the other sections (driver, mqtt, copydata, alarms,
commands) are given the mappings by gateway/app.py.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING, Annotated, Any, Literal, Union

from pydantic import Discriminator, Field, Tag, ValidationInfo, field_validator, model_validator

from gateway.alarms.config import AlarmsConfig, alarms_issues
from gateway.commands.config import CommandName, CommandSpec, command_issues
from gateway.config.jobs import JobsConfig
from gateway.model.definitions import MachineDefinition, Range, VariableDefinition
from gateway.model.types import TypeSpec
from gateway.settings.access import check_role_name
from gateway.settings.base import Strict, TypeField
from gateway.settings.compact import compact
from gateway.settings.mtconnect import VariableMTConnect
from gateway.settings.names import MACHINE_RE, RESERVED_SEGMENTS, SEGMENT_RE
from gateway.settings.sections import Sectioned, located_errors, with_sections
from gateway.sinks import registry as sinks
from gateway.sinks.copydata.config import MachineCopydata, VariableCopydata, copydata_issues
from gateway.sinks.mqtt.config import MachineMqtt, VariableMqtt
from gateway.sources import registry
from gateway.sources.base import ChecksVariables, DriverSettings, VariableSettings


def check_path(path: str) -> str:
    """A tree path: segments joined by '/', each a plain name."""
    if not path or path.startswith("/") or path.endswith("/"):
        raise ValueError(f"path {path!r} must be segments joined by '/', without a leading or trailing '/'")
    segments = path.split("/")
    for seg in segments:
        if not SEGMENT_RE.match(seg):
            raise ValueError(
                f"path segment {seg!r} in {path!r} must start with a letter, digit or '_' "
                "and contain only letters, digits, '_', '-' and '.'"
            )
    if segments[0].lower() in {r.lower() for r in RESERVED_SEGMENTS}:  # MQTT topics are lower-case
        raise ValueError(f"path {path!r} starts with {segments[0]!r}, which the gateway reserves for itself")
    return path


def _require_numeric(value: Any, info: ValidationInfo) -> None:
    upstream = info.data.get("type")
    if value is not None and upstream is not None and not upstream.is_numeric:
        raise ValueError(
            f"{info.field_name} is only allowed on numeric variables, and this one is {upstream}"
        )


class Scale(Strict):
    """Linear scaling: engineering = raw * gain + offset (and back again for writes)."""

    gain: float = 1.0
    offset: float = 0.0

    @field_validator("gain")
    @classmethod
    def _nonzero(cls, gain: float) -> float:
        if gain == 0:
            raise ValueError("gain must not be zero: scaling would not be reversible for writes")
        return gain


class EURange(Strict):
    """Engineering range: shown to OPC UA clients as EURange, and enforced on writes."""

    min: float
    max: float

    @model_validator(mode="after")
    def _ordered(self) -> EURange:
        if not self.min < self.max:
            raise ValueError(f"range min ({self.min}) must be below max ({self.max})")
        return self


class VariableSpec(Sectioned):
    """One mapped variable: where it lives on the controller and how it looks upstream."""

    path: Annotated[
        str, Field(description="Tree path, e.g. Axes/X/Position: OPC UA browse path and MQTT topic")
    ]
    source: Annotated[
        str, Field(min_length=1, description="Driver address, e.g. ns=2;s=::AsGlobalPV:gAxis[0].ActPos")
    ]
    type: TypeField
    source_type: TypeField | None = Field(
        default=None,
        description="The controller's own type, when scaling changes it (e.g. Int32 counts to Double mm)",
    )
    unit: str = ""
    access: Literal["read", "readwrite"] = "read"
    scale: Scale | None = None
    range: EURange | None = None
    deadband: float | str | None = Field(
        default=None,
        description="Absolute change below which updates are dropped, or a percentage of range: '0.5%'",
    )
    description: str = ""
    sampling_interval: float | None = Field(
        default=None, ge=0, description="Milliseconds; default from defaults"
    )
    queue_size: int | None = Field(default=None, ge=1, le=10000)
    mqtt: VariableMqtt | None = Field(
        default=None, description="How this variable appears in MQTT (topic, QoS, writes)"
    )
    copydata: VariableCopydata | None = Field(
        default=None, description="This variable's id in COPYDATA frames for nesting software: {id: 12}"
    )
    role: str | None = Field(
        default=None,
        description="Lowest role that may write it (access: readwrite); default: defaults.write_role",
    )
    mtconnect: VariableMTConnect | None = Field(
        default=None,
        description="How it appears in the MTConnect agent: {category: SAMPLE, type: POSITION, subType: "
        "ACTUAL, component: Axes/Linear[X]}",
    )

    @field_validator("path")
    @classmethod
    def _path(cls, path: str) -> str:
        return check_path(path)

    def model_post_init(self, context: Any, /) -> None:
        compact(self)  # a gateway holds one per variable, for as long as it runs

    @field_validator("source_type")
    @classmethod
    def _source_type(cls, value: TypeSpec | None, info: ValidationInfo) -> TypeSpec | None:
        upstream = info.data.get("type")
        if value is not None and upstream is not None:
            if value.array != upstream.array:
                raise ValueError(
                    f"source_type {value} and type {upstream} must both be arrays or both scalars"
                )
            if value.is_numeric != upstream.is_numeric:
                raise ValueError(f"source_type {value} and type {upstream} must both be numeric or both not")
        return value

    @field_validator("scale", "range")
    @classmethod
    def _numeric_only(cls, value: Any, info: ValidationInfo) -> Any:
        _require_numeric(value, info)
        return value

    @field_validator("deadband")
    @classmethod
    def _deadband(cls, value: float | str | None, info: ValidationInfo) -> float | str | None:
        if value is None:
            return None
        _require_numeric(value, info)
        if isinstance(value, str):
            m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*%\s*", value)
            if not m:
                raise ValueError(f"deadband {value!r} must be a number or a percentage such as '0.5%'")
            if float(m.group(1)) > 100:
                raise ValueError("a percentage deadband must be at most 100%")
            if info.data.get("range") is None:
                raise ValueError("a percentage deadband needs a range to be a percentage of")
            return value.strip()
        if value < 0:
            raise ValueError("deadband must not be negative")
        return value

    @field_validator("role")
    @classmethod
    def _role(cls, value: str | None, info: ValidationInfo) -> str | None:
        if value is None:
            return None
        check_role_name(value)
        if info.data.get("access") != "readwrite":
            raise ValueError("a role is only needed on variables with access: readwrite")
        return value

    @field_validator("mqtt")
    @classmethod
    def _mqtt(cls, value: VariableMqtt | None, info: ValidationInfo) -> VariableMqtt | None:
        if value is not None and value.writable and info.data.get("access") != "readwrite":
            raise ValueError("mqtt.writable: true needs access: readwrite")
        return value

    @property
    def writable(self) -> bool:
        return self.access == "readwrite"

    @property
    def raw_type(self) -> TypeSpec:
        return self.source_type or self.type

    @property
    def deadband_abs(self) -> float:
        """The deadband as an absolute amount in engineering units (0 = every change)."""
        if self.deadband is None:
            return 0.0
        if isinstance(self.deadband, str):
            assert self.range is not None
            return float(self.deadband.rstrip("%").strip()) / 100.0 * (self.range.max - self.range.min)
        return float(self.deadband)

    def definition(self) -> VariableDefinition:
        """What the variable tree knows of this variable (the MQTT and COPYDATA settings stay here)."""
        scale, rng = self.scale, self.range
        return VariableDefinition(
            path=self.path,
            type=self.type,
            source=self.source,
            source_type=self.source_type,
            unit=self.unit,
            description=self.description,
            writable=self.writable,
            role=self.role,
            gain=scale.gain if scale is not None else 1.0,
            offset=scale.offset if scale is not None else 0.0,
            deadband=self.deadband_abs,
            range=Range(rng.min, rng.max) if rng is not None else None,
        )


if not TYPE_CHECKING:  # with the keys sinks registered after the registry came add per variable
    VariableSpec = with_sections(VariableSpec, sinks.variable_sections())


def _driver_type(value: Any) -> str:
    """Which driver model a `driver:` section is; files from before the other drivers have no `type`."""
    if isinstance(value, dict):
        return str(value.get("type", registry.DEFAULT))
    return str(getattr(value, "type", registry.DEFAULT))


def _driver_union() -> Any:
    """`driver:` as pydantic validates it: the registered drivers' models, tagged by their type."""
    members = tuple(Annotated[spec.settings, Tag(spec.type)] for spec in registry.ordered())
    return Annotated[Union[members], Discriminator(_driver_type)]  # noqa: UP007 - built from a tuple


if TYPE_CHECKING:  # what the code may read of any driver's settings; each driver narrows to its own
    Driver = DriverSettings
else:
    Driver = _driver_union()


class VariableDefaults(Strict):
    sampling_interval: float = Field(default=100.0, ge=0, description="Milliseconds")
    queue_size: int = Field(default=1, ge=1, le=10000)
    write_role: str | None = Field(
        default=None,
        description="Lowest role that may write this machine's variables; default: the gateway's "
        "access.default_write_role",
    )

    @field_validator("write_role")
    @classmethod
    def _write_role(cls, value: str | None) -> str | None:
        return None if value is None else check_role_name(value)


class MachineMapping(Sectioned):
    """One machine: its name, its controller, and the variables mirrored upstream."""

    machine: Annotated[str, Field(description="Machine name: lower-case letters, digits, '-' and '_'")]
    description: str = ""
    driver: Driver
    defaults: VariableDefaults = VariableDefaults()
    variables: list[VariableSpec] = Field(min_length=1)
    mqtt: MachineMqtt | None = Field(
        default=None, description="This machine's MQTT defaults (QoS, retain, writes)"
    )
    jobs: JobsConfig | None = Field(
        default=None,
        description="The FTP job queue: program store on the controller, checks, retries, auto-start",
    )
    copydata: MachineCopydata | None = Field(
        default=None, description="COPYDATA targets: where this machine's frames for nesting software go"
    )
    alarms: AlarmsConfig | None = Field(
        default=None, description="Where the machine's active alarms come from, and how severe each class is"
    )
    commands: dict[CommandName, CommandSpec] | None = Field(
        default=None,
        description="Named commands (start, stop, select-program, ...): writes, guard, completion, timeout",
    )

    @field_validator("machine")
    @classmethod
    def _machine_name(cls, name: str) -> str:
        if not MACHINE_RE.match(name):
            raise ValueError(
                f"machine name {name!r} must be 1-63 lower-case letters, digits, '-' or '_', "
                "starting with a letter or digit"
            )
        return name

    @field_validator("variables")
    @classmethod
    def _read_only_driver(cls, variables: list[VariableSpec], info: ValidationInfo) -> list[VariableSpec]:
        """A read-only driver (MTConnect agent or adapter) cannot write: its variables are access: read."""
        driver = info.data.get("driver")
        spec = registry.find(driver.type) if driver is not None else None
        if spec is not None and spec.read_only is not None:
            message = f"a {spec.type} driver is read-only ({spec.read_only}): use access: read"
            located_errors([((i, "access"), message) for i, var in enumerate(variables) if var.writable])
        if isinstance(driver, ChecksVariables):  # a driver's own checks across its variables
            located_errors(driver.variable_issues(variables))
        return variables

    @field_validator("jobs")
    @classmethod
    def _jobs_variables(cls, jobs: JobsConfig | None, info: ValidationInfo) -> JobsConfig | None:
        """auto.select/start/ready must name mapped variables of a fitting type."""
        variables = info.data.get("variables")
        if jobs is None or jobs.auto is None or variables is None:
            return jobs
        by_path = {v.path: v for v in variables}
        auto = jobs.auto
        wanted: list[tuple[str, str | None, str | None, bool]] = [
            ("select", auto.select, "String", True),
            ("start", auto.start, "Boolean", True),
        ]
        if auto.ready is not None:
            wanted.append(("ready.path", auto.ready.path, None, False))
        for key, path, type_name, writable in wanted:
            if path is None:
                continue
            var = by_path.get(path)
            if var is None:
                raise ValueError(f"auto.{key}: {path!r} is not a variable of this mapping")
            if type_name is not None and str(var.type) != type_name:
                raise ValueError(f"auto.{key}: {path} is {var.type}, expected {type_name}")
            if writable and not var.writable:
                raise ValueError(f"auto.{key}: {path} must have access: readwrite")
        return jobs

    @field_validator("alarms")
    @classmethod
    def _alarm_variables(cls, alarms: AlarmsConfig | None, info: ValidationInfo) -> AlarmsConfig | None:
        """The alarm arrays must be variables of this mapping, of fitting types (errors at their own keys)."""
        variables = info.data.get("variables")
        if alarms is not None and variables is not None:
            located_errors(alarms_issues(alarms, variables))
        return alarms

    @field_validator("commands")
    @classmethod
    def _command_variables(
        cls, commands: dict[CommandName, CommandSpec] | None, info: ValidationInfo
    ) -> dict[CommandName, CommandSpec] | None:
        """Writes and conditions must name variables of this mapping, with values that fit them."""
        variables = info.data.get("variables")
        if commands is not None and variables is not None:
            located_errors(command_issues(commands, variables))
        return commands

    @model_validator(mode="after")
    def _copydata_cross_checks(self) -> MachineMapping:
        """Ids unique per machine, targets naming variables with ids, ids that fit the id width."""
        copydata_issues(self.variables, self.copydata)
        return self

    def definition(self) -> MachineDefinition:
        """What the variable tree knows of this machine (gateway/model/definitions.py)."""
        return MachineDefinition(
            name=self.machine,
            variables=tuple(v.definition() for v in self.variables),
            description=self.description,
            write_role=self.defaults.write_role,
            endpoint=self.driver.endpoint,
            acknowledge_role=self.alarms.acknowledge_role if self.alarms is not None else None,
        )

    def sampling_interval(self, var: VariableSettings) -> float:
        return self.defaults.sampling_interval if var.sampling_interval is None else var.sampling_interval

    def queue_size(self, var: VariableSettings) -> int:
        return self.defaults.queue_size if var.queue_size is None else var.queue_size


if not TYPE_CHECKING:  # with the keys sinks and OPC UA extensions add per machine (umati: ...)
    MachineMapping = with_sections(MachineMapping, sinks.machine_sections())


def tree_conflicts(paths: list[str]) -> list[tuple[int, str]]:
    """Structural problems across variables: (index of offending entry, message).

    Pydantic validates entries one by one; these need the whole list.
    """
    problems: list[tuple[int, str]] = []
    first: dict[str, int] = {}
    for index, path in enumerate(paths):
        if path in first:
            problems.append((index, f"duplicate path {path!r} (first used by variables[{first[path]}])"))
        else:
            first[path] = index
    for index, path in enumerate(paths):
        if first.get(path) != index:
            continue
        segments = path.split("/")
        for cut in range(1, len(segments)):
            folder = "/".join(segments[:cut])
            if folder in first:
                problems.append(
                    (
                        index,
                        (
                            f"path {path!r} uses {folder!r} as a folder, "
                            f"but variables[{first[folder]}] is a variable"
                        ),
                    )
                )
    return problems

"""The `umati:` section of a mapping file: which variable (or constant) fills which umati node.

Each value is either a constant (a YAML scalar) or `{variable: <path>, values: {<machine value>: <umati
name>}}`: the umati node then shows that variable's samples, the same ones as the gateway's own node,
with `values` translating the machine's codes into the umati enumeration's names (ChannelState,
ChannelMode, MachineOperationMode, LaserState, and the ProductionProgramStateMachine's states).
Enumeration names are checked here, variables against the mapping's (`check`), so that a typo is a
`file:line: umati.<key>: ...` error and never a node with a wrong value.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from typing import Any

from pydantic import Field

from gateway.settings.base import Strict
from gateway.settings.sections import Loc

# The enumerations of OPC 40501-1 v1.02 (Opc.Ua.MachineTool.NodeSet2.xml; tests compare them with it).
CHANNEL_STATE = ("Active", "Interrupted", "Reset")
CHANNEL_MODE = (
    "Automatic",
    "MdaMdi",
    "JogManual",
    "JogIncrement",
    "TeachingHandle",
    "Remote",
    "Reference",
    "Other",
)
OPERATION_MODE = ("Manual", "Automatic", "Setup", "AutoWithManualIntervention", "Service", "Other")
LASER_STATE = ("Undefined", "Ready", "Active", "Error")
PROGRAM_STATES = ("Initializing", "Running", "Ended", "Interrupted", "Aborted")

# MachineToolIdentificationType's properties (with those of MachineryItemIdentificationType) that hold
# a scalar, with their DataType: String, LocalizedText, UInt16 or Byte (MonthOfConstruction), DateTime.
IDENTIFICATION: dict[str, str] = {
    "Manufacturer": "LocalizedText",
    "SerialNumber": "String",
    "ProductInstanceUri": "String",
    "Model": "LocalizedText",
    "SoftwareRevision": "String",
    "HardwareRevision": "String",
    "YearOfConstruction": "UInt16",
    "MonthOfConstruction": "Byte",
    "ManufacturerUri": "String",
    "ProductCode": "String",
    "DeviceClass": "String",
    "AssetId": "String",
    "ComponentName": "LocalizedText",
    "Location": "String",
    "InitialOperationDate": "DateTime",
}
MANDATORY_IDENTIFICATION = ("Manufacturer", "SerialNumber", "ProductInstanceUri")

Constant = str | int | float | bool

# The gateway's own variables of every machine (gateway/model/status.py) a view may show too, and those of
# a machine with `jobs:` (gateway/jobs/queue/publish.py).
GATEWAY_VARIABLES = ("Status/Connected", "Status/State", "Status/LastError", "Status/ReconnectCount")
JOB_VARIABLES = ("Jobs/Current", "Jobs/LastDelivered", "Jobs/QueueLength", "Jobs/Progress", "Jobs/LastFailed")


class Binding(Strict):
    """A umati node that shows a variable of the mapping."""

    variable: str = Field(description="A variable of this mapping (its path)")
    values: dict[str | int | bool, str | int | float | bool] | None = Field(
        default=None,
        description="The machine's values -> the umati node's: an enumeration's or a state's names, else "
        "constants of the node's type (a value not listed shows BadTypeMismatch)",
    )
    scale: float | None = Field(
        default=None, description="A factor for numbers (seconds to PowerOnDuration's hours: 0.000277778)"
    )


Source = Binding | Constant


class Software(Strict):
    """A SoftwareIdentificationType under Identification/SoftwareIdentification (a controller's …)."""

    name: str = Field(min_length=1, description="Its BrowseName (Controller …)")
    identifier: Binding | str = Field(description="Identifier: what the software is")
    revision: Binding | str = Field(description="SoftwareRevision")


class Channel(Strict):
    """A ChannelMonitoringType under Monitoring: one NC channel (a path)."""

    name: str = Field(default="Channel1", min_length=1, description="Its BrowseName and Name")
    state: Binding = Field(description="ChannelState: Active, Interrupted or Reset")
    mode: Binding | str = Field(description="ChannelMode: Automatic, MdaMdi, JogManual … Other")
    feed_override: Binding | float = Field(description="FeedOverride in percent")
    rapid_override: Binding | None = Field(default=None, description="RapidOverride in percent")


class Laser(Strict):
    """A LaserMonitoringType under Monitoring: the working unit of a laser cutter."""

    name: str = Field(default="Laser", min_length=1)
    controller_is_on: Binding | bool = Field(description="ControllerIsOn (Boolean)")
    laser_state: Binding = Field(description="LaserState: Undefined, Ready, Active or Error")


class Spindle(Strict):
    """A SpindleMonitoringType under Monitoring: the working unit of a milling machine or lathe."""

    name: str = Field(min_length=1)
    is_rotating: Binding = Field(description="IsRotating (Boolean)")
    override: Binding | None = Field(default=None, description="Override in percent")


class Program(Strict):
    """Production/ActiveProgram."""

    name: Binding | str = Field(description="The active program's name")
    number_in_list: Binding | int = Field(default=0, description="NumberInList (UInt16)")
    state: Binding = Field(
        description="The ProductionProgramStateMachine's state: Initializing, Running, Ended, "
        "Interrupted or Aborted"
    )
    job_identifier: Binding | None = Field(
        default=None,
        description="ActiveProgram/JobIdentifier: the gateway's Jobs/LastDelivered ties it to the job queue "
        "(with jobs.auto, the job the machine was given to run)",
    )


class UmatiView(Strict):
    """The machine as an OPC 40501 MachineTool under the Machinery Machines folder."""

    namespace: str | None = Field(
        default=None,
        min_length=1,
        description="The namespace URI of this machine's instance nodes (umati's showcase asks one per "
        "machine); default: the gateway's own namespace",
    )
    identification: dict[str, Source] = Field(
        description="MachineToolIdentificationType properties: Manufacturer, SerialNumber, "
        "ProductInstanceUri (mandatory), Model, SoftwareRevision, YearOfConstruction …"
    )
    software: list[Software] = Field(
        default_factory=list, description="Identification/SoftwareIdentification: the software installed"
    )
    operation_mode: Binding | str = Field(
        default="Other", description="Monitoring/MachineTool/OperationMode (MachineOperationMode)"
    )
    power_on_duration: Binding | None = Field(
        default=None, description="Monitoring/MachineTool/PowerOnDuration in hours (UInt32)"
    )
    feed_override: Binding | None = Field(
        default=None, description="Monitoring/MachineTool/FeedOverride in percent"
    )
    channels: list[Channel] = Field(default_factory=list)
    laser: Laser | None = None
    spindles: list[Spindle] = Field(default_factory=list)
    program: Program
    messages: bool = Field(
        default=True,
        description="Notification/Messages: the machine's alarms as NotificationEventType events",
    )


ENUMS: dict[str, tuple[str, ...]] = {
    "operation_mode": OPERATION_MODE,
    "state": CHANNEL_STATE,
    "mode": CHANNEL_MODE,
    "laser_state": LASER_STATE,
    "program.state": PROGRAM_STATES,
}


def bindings(view: UmatiView) -> Iterator[tuple[Loc, Source, tuple[str, ...] | None]]:
    """Every value of the section, where it is, and the names its `values` may use (enumerations)."""
    for key, source in view.identification.items():
        yield ("identification", key), source, None
    for i, software in enumerate(view.software):
        yield ("software", i, "identifier"), software.identifier, None
        yield ("software", i, "revision"), software.revision, None
    yield ("operation_mode",), view.operation_mode, OPERATION_MODE
    if view.power_on_duration is not None:
        yield ("power_on_duration",), view.power_on_duration, None
    if view.feed_override is not None:
        yield ("feed_override",), view.feed_override, None
    for i, channel in enumerate(view.channels):
        yield ("channels", i, "state"), channel.state, CHANNEL_STATE
        yield ("channels", i, "mode"), channel.mode, CHANNEL_MODE
        yield ("channels", i, "feed_override"), channel.feed_override, None
        if channel.rapid_override is not None:
            yield ("channels", i, "rapid_override"), channel.rapid_override, None
    if view.laser is not None:
        yield ("laser", "controller_is_on"), view.laser.controller_is_on, None
        yield ("laser", "laser_state"), view.laser.laser_state, LASER_STATE
    for i, spindle in enumerate(view.spindles):
        yield ("spindles", i, "is_rotating"), spindle.is_rotating, None
        if spindle.override is not None:
            yield ("spindles", i, "override"), spindle.override, None
    yield ("program", "name"), view.program.name, None
    yield ("program", "number_in_list"), view.program.number_in_list, None
    yield ("program", "state"), view.program.state, PROGRAM_STATES
    if view.program.job_identifier is not None:
        yield ("program", "job_identifier"), view.program.job_identifier, None


def check(view: UmatiView, earlier: Mapping[str, Any]) -> Iterable[tuple[Loc, str]]:
    """The section against the rest of the mapping file (`earlier`: its keys validated before)."""
    variables = {v.path for v in earlier.get("variables", ())} | set(GATEWAY_VARIABLES)
    if earlier.get("jobs") is not None:
        variables |= set(JOB_VARIABLES)
    for key in view.identification:
        if key not in IDENTIFICATION:
            yield (
                ("identification", key),
                (
                    f"{key!r} is not a property of MachineToolIdentificationType this view fills "
                    f"(one of: {', '.join(IDENTIFICATION)})"
                ),
            )
    for key in MANDATORY_IDENTIFICATION:
        if key not in view.identification:
            yield ("identification",), f"{key} is mandatory (MachineToolIdentificationType)"
    for loc, source, enum in bindings(view):
        if isinstance(source, Binding):
            # A job variable names the machine's job queue: bound when the mapping has `jobs:`, else the
            # node stays empty (the laser's default map binds JobIdentifier, and a copy of it without a
            # queue is still a valid mapping).
            job_queue_absent = source.variable in JOB_VARIABLES and earlier.get("jobs") is None
            if source.variable not in variables and not job_queue_absent:
                yield (*loc, "variable"), f"{source.variable!r} is not a variable of this mapping"
            for code, name in (source.values or {}).items():
                if enum is not None and name not in enum:
                    yield (*loc, "values", str(code)), (f"{name!r} is not one of {', '.join(enum)}")
        elif enum is not None and loc[-1] != "state" and str(source) not in enum:
            yield loc, f"{source!r} is not one of {', '.join(enum)}"


def conformance_units(view: UmatiView) -> list[str]:
    """The conformance units of OPC 40501-1 (its documentation CSV) that a view so configured fills."""
    units = ["MachineTool MachineToolType Mandatory Nodes", "MachineTool Production Basic"]
    extra = set(view.identification) - set(MANDATORY_IDENTIFICATION)
    if extra & {"Model", "YearOfConstruction", "MonthOfConstruction", "SoftwareRevision", "HardwareRevision"}:
        units.append("MachineTool Identification Machinery additional")
    if view.software:
        units.append("MachineTool Identification SoftwareInformation")
    if view.channels:
        units.append("MachineTool Monitoring Basic - Channels")
    if view.power_on_duration is not None:
        units.append("MachineTool Monitoring Basic - PowerOnDuration")
    if view.laser is not None or view.spindles:
        units.append("MachineTool Monitoring WorkingUnit")
    units.append("MachineTool Production ProductionProgramStateMachineType")
    if view.messages:
        units.append("MachineTool Notification \u2013 Errors and Alerts")  # an en dash, as the CSV has it
    return units


def report(view: UmatiView) -> Iterable[str]:
    """What `cnc-gateway check` prints under the machine."""
    yield "umati: MachineTool (OPC 40501-1) under Objects/Machines (OPC 40001-1)"
    for loc, source, _ in bindings(view):
        where = ".".join(str(part) for part in loc)
        shown = f"<- {source.variable}" if isinstance(source, Binding) else f"= {source!r}"
        yield f"  {where} {shown}"
    yield "  conformance units filled: " + "; ".join(conformance_units(view))

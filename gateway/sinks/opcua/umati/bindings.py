"""Which node of the MachineTool instance each value of a `umati:` section fills (by path below it)."""

from __future__ import annotations

from dataclasses import dataclass

from gateway.sinks.opcua.umati.config import (
    CHANNEL_MODE,
    CHANNEL_STATE,
    LASER_STATE,
    OPERATION_MODE,
    PROGRAM_STATES,
    Source,
    UmatiView,
)


@dataclass(frozen=True)
class Bound:
    """One umati node and what fills it."""

    path: str  # below the MachineTool instance
    source: Source
    enum: tuple[str, ...] | None = None  # the names of its enumeration (or states)


def bindings(view: UmatiView) -> list[Bound]:
    """Which umati node (by path below the instance) each value of the section fills."""
    out = [Bound(f"Identification/{key}", source) for key, source in view.identification.items()]
    for software in view.software:
        base = f"Identification/SoftwareIdentification/{software.name}"
        out.append(Bound(f"{base}/Identifier", software.identifier))
        out.append(Bound(f"{base}/SoftwareRevision", software.revision))
    out.append(Bound("Monitoring/MachineTool/OperationMode", view.operation_mode, OPERATION_MODE))
    if view.power_on_duration is not None:
        out.append(Bound("Monitoring/MachineTool/PowerOnDuration", view.power_on_duration))
    if view.feed_override is not None:
        out.append(Bound("Monitoring/MachineTool/FeedOverride", view.feed_override))
    for channel in view.channels:
        base = f"Monitoring/{channel.name}"
        out.append(Bound(f"{base}/Name", channel.name))
        out.append(Bound(f"{base}/ChannelState", channel.state, CHANNEL_STATE))
        out.append(Bound(f"{base}/ChannelMode", channel.mode, CHANNEL_MODE))
        out.append(Bound(f"{base}/FeedOverride", channel.feed_override))
        if channel.rapid_override is not None:
            out.append(Bound(f"{base}/RapidOverride", channel.rapid_override))
    if view.laser is not None:
        base = f"Monitoring/{view.laser.name}"
        out.append(Bound(f"{base}/Name", view.laser.name))
        out.append(Bound(f"{base}/ControllerIsOn", view.laser.controller_is_on))
        out.append(Bound(f"{base}/LaserState", view.laser.laser_state, LASER_STATE))
    for spindle in view.spindles:
        base = f"Monitoring/{spindle.name}"
        out.append(Bound(f"{base}/Name", spindle.name))
        out.append(Bound(f"{base}/IsRotating", spindle.is_rotating))
        if spindle.override is not None:
            out.append(Bound(f"{base}/Override", spindle.override))
    program = "Production/ActiveProgram"
    out.append(Bound(f"{program}/Name", view.program.name))
    out.append(Bound(f"{program}/NumberInList", view.program.number_in_list))
    if view.program.job_identifier is not None:
        out.append(Bound(f"{program}/JobIdentifier", view.program.job_identifier))
    state = view.program.state
    out.append(Bound(f"{program}/State/CurrentState", state, PROGRAM_STATES))
    out.append(Bound(f"{program}/State/CurrentState/Id", state, PROGRAM_STATES))
    out.append(Bound(f"{program}/State/CurrentState/Number", state, PROGRAM_STATES))
    return out

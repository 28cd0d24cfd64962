"""A serial machine's drip-feed commands (pause, resume, abort, and restart a job at a line) and its line's
status variables.

Registered on the machine's `Commands` object (gateway.model.methods), so OPC UA
shows them as Method nodes beside the mapping's commands and MQTT takes them as
`<prefix>/<machine>/commands/<name>` requests: the role check and the audit entry
are `Machine.call_method`'s, the same for every door. Restart goes through the
queue like `cnc-gateway jobs retry` (a FAILED job, queued again), with the line
its next delivery starts at; the job service passes that in as `restart`.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Sequence
from typing import Any

from gateway.model.context import WriteContext
from gateway.model.methods import Argument, Method
from gateway.model.tree import Machine
from gateway.model.types import TypeSpec
from gateway.transports.dnc.transport import SerialTransport

OBJECT = "Commands"
ROLE = "operator"

#: (job id, line, user) -> the job's record, queued again; raises RequestError.
Restart = Callable[[str, int, str], Awaitable[dict[str, Any]]]

JOB = Argument("Job", TypeSpec.parse("String"), "Job id, e.g. J000042 (a FAILED drip-feed)")
LINE = Argument("Line", TypeSpec.parse("UInt32"), "Program line to restart at (the job's reason names it)")
RESULT = Argument("Result", TypeSpec.parse("String"), "What was done")


def drip_methods(line: SerialTransport, restart: Restart) -> list[Method]:
    """The four methods for one serial machine."""

    async def pause(_ctx: WriteContext, _args: Sequence[Any]) -> Sequence[Any]:
        return (line.pause(),)

    async def resume(_ctx: WriteContext, _args: Sequence[Any]) -> Sequence[Any]:
        return (line.resume(),)

    async def abort(ctx: WriteContext, _args: Sequence[Any]) -> Sequence[Any]:
        return (line.abort(ctx.user or ctx.origin),)

    async def restart_at(ctx: WriteContext, args: Sequence[Any]) -> Sequence[Any]:
        record = await restart(str(args[0]), int(args[1]), ctx.user or ctx.origin)
        return (f"{record['id']} queued to restart at line {int(args[1])}",)

    def method(name: str, description: str, handler: Any, inputs: tuple[Argument, ...] = ()) -> Method:
        return Method(OBJECT, name, description, inputs, (RESULT,), handler, role=ROLE)

    return [
        method("DripPause", "Hold the drip-feed being sent (the controller runs what it holds)", pause),
        method("DripResume", "Go on with a paused drip-feed", resume),
        method("DripAbort", "Stop the drip-feed being sent; its job is FAILED with the line reached", abort),
        method(
            "DripRestart",
            "Send a FAILED drip-feed again from a line: its header, the modal state, then that line on",
            restart_at,
            (JOB, LINE),
        ),
    ]


def line_status(machine: Machine) -> Callable[[SerialTransport], None]:
    """`Status/DncParityErrors` and `Status/DncLineCheck` for a serial machine, and the callback that keeps
    them (SerialTransport.on_figures): a line whose characters come with the wrong parity bit, or whose
    DC1/DC3 say the device server is set up otherwise than the mapping, says so where the operator looks."""
    errors = machine.add_internal(
        "Status/DncParityErrors",
        "UInt32",
        "Characters from the controller with a wrong parity bit since the start (DC1/DC3 among them are "
        "obeyed all the same)",
        0,
    )
    check = machine.add_internal(
        "Status/DncLineCheck",
        "String",
        "What the serial line's characters say of its settings (software_parity, the character format); "
        "empty when they fit",
        "",
    )

    def update(line: SerialTransport) -> None:
        machine.set_internal(errors, line.parity_errors % 2**32)
        machine.set_internal(check, line.hint)

    return update

"""The serial DNC machines of a gateway, assembled: their lines, punch desks, drip-feed methods, the one
fleet their drip-feeds share, the transfer log, and the shell's drip-feed commands.

Built once by the job service (through this transport's spec) with every machine whose
`jobs.controller` is serial: each line gets its fleet, its alarm reader, its status
callback and its punch desk as it is made, never patched in afterwards. Entered once the
job queue is open (the transfer log is opened then, in the queue's thread), left before it
closes; `run()` runs the lines, the desks and the shell's commands, until cancelled.
"""

from __future__ import annotations

import asyncio
import functools
import logging
from collections.abc import Callable, Sequence
from typing import Self

from gateway.errors import RequestError, SinkError, StoreError
from gateway.model.context import WriteContext
from gateway.model.tree import Machine
from gateway.transports.base import CorePorts, Delivery, MachineJobs, settings_of
from gateway.transports.dnc.config import AlarmWhen, ControllerSerial
from gateway.transports.dnc.control import (
    ControlReply,
    ControlRequest,
    answer,
    control_dir,
    folder_problem,
    make_control_dir,
    take_requests,
)
from gateway.transports.dnc.desk import PunchDesk
from gateway.transports.dnc.fleet import DripFleet
from gateway.transports.dnc.idle import SendAnswer
from gateway.transports.dnc.methods import drip_methods, line_status
from gateway.transports.dnc.punch import PunchSettings
from gateway.transports.dnc.received import ReceivedStore
from gateway.transports.dnc.transfers import TransferLog
from gateway.transports.dnc.transport import SerialTransport, request_restart

log = logging.getLogger("gateway.jobs")

CONTROL_EVERY = 0.2  # s between looks for drip-feed commands from the shell (jobs pause|resume|abort)


class SerialLines:
    """`Deliveries` of the serial transport: every serial machine's line, and its desk where it has
    `jobs.punch`."""

    def __init__(self, machines: Sequence[MachineJobs], core: CorePorts) -> None:
        self.core = core
        self.tree_machines: dict[str, Machine] = {m.name: m.machine for m in machines}
        settings = {m.name: settings_of(m.jobs.controller, ControllerSerial) for m in machines}
        # One scheduler for every drip-feed: lines that share a device server share its capacity.
        fleet = DripFleet.for_lines(settings.items())
        self.lines: dict[str, SerialTransport] = {}
        self.desks: dict[str, PunchDesk] = {}
        self.machines: dict[str, Delivery] = {}
        self.transfer_log: TransferLog | None = None  # opened on entry
        self._entered = False
        for m in machines:
            punch = m.jobs.punch if isinstance(m.jobs.punch, PunchSettings) else None
            line = self.lines[m.name] = SerialTransport(
                settings[m.name],
                machine=m.name,
                state_dir=core.state_dir,
                fleet=fleet,
                alarm=alarm_reader(m.machine, settings[m.name].alarm_when),
                on_figures=line_status(m.machine),
                listener=None if punch is None else functools.partial(self._desk, m, punch),
            )
            for method in drip_methods(line, m.restart):
                m.machine.add_method(method)
            requests = None if punch is None else punch.requests
            keep = requests.keep_delivered if requests is not None and "queue" in requests.sources else 0
            self.machines[m.name] = Delivery(line, restart_at=request_restart, keep_delivered=keep)

    def _desk(self, m: MachineJobs, punch: PunchSettings, send_answer: SendAnswer) -> PunchDesk:
        """What an idle line hears (jobs.punch): the line owner takes its machine's desk."""
        core = self.core
        desk = self.desks[m.name] = PunchDesk(
            m.machine,
            punch,
            store=ReceivedStore(core.state_dir),
            validate=m.validate,
            backups=core.backups_dir / m.name,
            submit=core.submit,
            find_job=core.find_job,
            send_answer=send_answer,
            blocking=core.work,
        )
        return desk

    async def __aenter__(self) -> Self:
        try:
            log_file = await self.core.queue_thread(TransferLog.in_state_dir, self.core.state_dir)
        except StoreError as exc:
            raise SinkError(str(exc)) from None
        self.transfer_log = log_file
        for line in self.lines.values():
            line.transfer_log = log_file
        for desk in self.desks.values():
            desk.transfers = log_file
        self._entered = True
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        for line in self.lines.values():
            line.close()
        if self._entered:
            self._entered = False
            for desk in self.desks.values():
                await desk.drain()
        if self.transfer_log is not None:
            await self.core.queue_thread(self.transfer_log.close)
            self.transfer_log = None

    async def run(self) -> None:
        async with asyncio.TaskGroup() as tg:
            for name, desk in self.desks.items():
                tg.create_task(desk.run(), name=f"jobs:punch:{name}")
            for name, line in self.lines.items():
                tg.create_task(line.run(), name=f"jobs:dnc-line:{name}")
            tg.create_task(self._shell_commands(), name="jobs:dnc-control")

    async def _shell_commands(self) -> None:
        """`cnc-gateway jobs pause|resume|abort MACHINE` (control.py), until cancelled. Nothing is taken
        from a control folder that is not the gateway's own; why is logged once."""
        state = self.core.state_dir
        try:
            await asyncio.to_thread(make_control_dir, state)
        except OSError as exc:
            log.warning("cannot make %s: %s", control_dir(state), exc.strerror or exc)
        said: str | None = None
        while True:
            problem = await asyncio.to_thread(folder_problem, state)
            if problem != said:
                if problem is not None:
                    log.error("drip-feed commands from the shell (jobs pause|resume|abort) are refused: %s",
                              problem)  # fmt: skip
                else:
                    log.info("drip-feed commands from the shell are taken again: %s is the gateway's own",
                             control_dir(state))  # fmt: skip
                said = problem
            for request in await asyncio.to_thread(take_requests, state):
                reply = await self.shell_command(request)
                try:
                    await asyncio.to_thread(answer, request, reply)
                except OSError as exc:
                    log.warning("%s: cannot answer %s: %s", request.machine, request.path.name, exc)
            await asyncio.sleep(CONTROL_EVERY)

    async def shell_command(self, request: ControlRequest) -> ControlReply:
        """One drip-feed command from the shell, as a method call of origin `cli` (role checked, audited)."""
        machine = self.tree_machines.get(request.machine)
        method = None if machine is None else machine.methods.get(("Commands", request.method))
        if machine is None or method is None:
            return ControlReply("BadNotFound", f"{request.machine} has no serial line here")
        try:
            result = await machine.call_method(method, [], WriteContext("cli", request.user, method.role))
        except RequestError as exc:
            return ControlReply(exc.status, exc.reason)
        log.info("%s: %s from the shell by %s: %s", request.machine, request.method, request.user, result[0])
        return ControlReply("Good", str(result[0]))


def alarm_reader(machine: Machine, when: AlarmWhen | None) -> Callable[[], str | None] | None:
    """Reads the variable a serial machine's `alarm_when` names (from the line's thread: one attribute
    read); None without one, or when the variable is not mapped (logged)."""
    if when is None:
        return None
    node = machine.nodes.get(when.path)
    if node is None:
        log.warning("%s: alarm_when names %s, which is not mapped: ignored", machine.name, when.path)
        return None

    def read() -> str | None:
        sample = node.sample
        return (
            f"{when.path} = {sample.value!r}" if sample is not None and sample.value == when.equals else None
        )

    return read

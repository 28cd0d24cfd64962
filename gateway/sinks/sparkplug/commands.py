"""NCMD and DCMD: a host's requests, carried out through the tree's one write path, or refused.

Sparkplug has no reply topic, so every outcome shows where a host looks:
- a write goes through `Machine.write_node` (read-only, role, type, range, scaling, the controller's
  answer, the audit trail), with origin "sparkplug" and the machine's MQTT writers' role; an
  accepted write shows as the variable's next DDATA (the controller's value, read back); a refused
  one as a DDATA of the value the variable still has;
- a command (`Commands/<name>/Execute`) goes through `Machine.call_method`, with the same guards,
  deadline and audit as over MQTT or OPC UA; `Commands/<name>/Result` says how it ended;
- `Node Control/Rebirth` asks for NBIRTH and every DBIRTH again.

Refusals are logged (with a quota, so junk cannot flood the log), audited when they name a known
metric, and counted by kind (`refusals`): the codec's kinds for what cannot be read (malformed
protobuf, unknown alias, wrong datatype, …), the status name for what the write path refused
(BadUserAccessDenied, BadOutOfRange, …). Which variables DCMD may write, and whether commands are
open, follows the mapping's `mqtt:` settings (`writable`, per variable too, and `commands`): both
doors are MQTT, through the same broker and its ACL.

Writes to one machine are carried out in order, one at a time, from a bounded queue; commands,
which wait for their completion, up to MAX_RUNNING at once, so that a stop is not held behind a
start waiting for its deadline.
"""

from __future__ import annotations

import asyncio
import logging
from collections import Counter
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass
from typing import Any

from gateway.codecs.sparkplug import (
    NAMESPACE,
    Command,
    MessageType,
    MetricTable,
    SparkplugError,
    WrongDatatype,
    decode_dcmd,
    decode_ncmd,
)
from gateway.errors import (
    AccessDenied,
    CallError,
    MalformedRequest,
    NotWritable,
    RequestError,
    TypeMismatch,
    WriteError,
)
from gateway.model.context import WriteContext
from gateway.model.tree import VariableTree
from gateway.sinks.mqtt_link.client import Incoming
from gateway.sinks.mqtt_link.requests import LogQuota, TooManyWrites, carry_out
from gateway.sinks.sparkplug.devices import CommandMetric, Device, VariableMetric, now_ms

log = logging.getLogger(__name__)

ORIGIN = "sparkplug"


@dataclass(frozen=True, slots=True)
class Outcomes:
    """What the sink does with the results (it owns the session and the sequence numbers)."""

    rebirth: Callable[[], None]
    show_variable: Callable[[VariableMetric], Awaitable[None]]  # a DDATA with the value it has now
    show_command: Callable[[Device, CommandMetric], Awaitable[None]]  # Execute at rest, and Result


@dataclass(slots=True)
class _Write:
    metric: VariableMetric
    value: Any


@dataclass(slots=True)
class _Call:
    command: CommandMetric
    args: list[Any]


class Requests:
    """Turns NCMD and DCMD messages into rebirths, writes and command calls; counts what it refuses."""

    def __init__(
        self,
        tree: VariableTree,
        group_id: str,
        edge_node_id: str,
        devices: Mapping[str, Device],
        node_table: Callable[[], MetricTable],
        outcomes: Outcomes,
        max_pending: int,
    ) -> None:
        self.tree = tree
        self.devices = devices
        self.node_table = node_table
        self.outcomes = outcomes
        self.ncmd_topic = f"{NAMESPACE}/{group_id}/{MessageType.NCMD.value}/{edge_node_id}"
        self.dcmd_prefix = f"{NAMESPACE}/{group_id}/{MessageType.DCMD.value}/{edge_node_id}/"
        self.writes: dict[str, asyncio.Queue[_Write]] = {
            name: asyncio.Queue(maxsize=max_pending) for name in devices
        }
        self.calls: dict[str, asyncio.Queue[_Call]] = {
            name: asyncio.Queue(maxsize=max_pending) for name, d in devices.items() if d.commands
        }
        self.max_pending = max_pending
        self.received = 0  # NCMD and DCMD messages
        self.accepted = 0  # writes and calls carried out
        self.rebirths = 0
        self.refusals: Counter[str] = Counter()
        self._quota = LogQuota()
        self._shown: set[asyncio.Future[None]] = set()

    @property
    def refused(self) -> int:
        return sum(self.refusals.values())

    # --- from paho, on the loop ----------------------------------------------------------------

    def handle(self, msg: Incoming) -> bool:
        """An NCMD or DCMD of this edge node (carried out or refused): True. Any other message: False."""
        topic = msg.topic
        if topic == self.ncmd_topic:
            self.received += 1
            self._ncmd(msg)
            return True
        if topic.startswith(self.dcmd_prefix):
            self.received += 1
            self._dcmd(topic[len(self.dcmd_prefix) :], msg)
            return True
        return False

    def _ncmd(self, msg: Incoming) -> None:
        if msg.retain:
            self.refuse(
                "retained", "NCMD", "retained commands are ignored: publish them without the retain flag"
            )
            return
        try:
            command = decode_ncmd(msg.payload, self.node_table())
        except SparkplugError as exc:
            self.refuse(exc.kind, "NCMD", str(exc))
            return
        for refusal in command.refusals:
            self.refuse(refusal.kind, "NCMD", str(refusal))
        for write in command.writes:  # the node's own metrics are for reading
            self.refuse(
                NotWritable.status, "NCMD", f"{write.metric.name}: the edge node's metrics are read-only"
            )
        if command.rebirth:
            self.rebirths += 1
            log.info("Sparkplug: a host asked for a rebirth")
            self.outcomes.rebirth()

    def _dcmd(self, device_id: str, msg: Incoming) -> None:
        device = self.devices.get(device_id)
        where = f"DCMD to {device_id[:80]}"
        if device is None:
            self.refuse("unknown_device", where, "this edge node has no such device")
            return
        if msg.retain:
            self.refuse(
                "retained", where, "retained commands are ignored: publish them without the retain flag"
            )
            return
        try:
            command = decode_dcmd(msg.payload, device.table)
        except SparkplugError as exc:
            self.refuse(exc.kind, where, str(exc))
            return
        self._carry_out(device, command)

    def _carry_out(self, device: Device, command: Command) -> None:
        where = f"DCMD to {device.name}"
        ctx = self._context(device)
        for refusal in command.refusals:
            self.refuse(refusal.kind, where, str(refusal))
            target = device.targets.get(refusal.metric or "")
            text = str(refusal)
            error = TypeMismatch(text) if isinstance(refusal, WrongDatatype) else MalformedRequest(text)
            if isinstance(target, VariableMetric):  # a known metric: worth an audit entry; junk is not
                device.machine.audit_write(target.node, target.node.sample.value, None, ctx, error)
            elif isinstance(target, CommandMetric):
                device.machine.audit_call(target.method, [], ctx, error)
        for write in command.writes:
            target = device.targets.get(write.metric.name)
            if isinstance(target, VariableMetric):
                self._write(device, target, write.value, ctx)
            elif isinstance(target, CommandMetric) and write.metric.name == target.execute:
                self._call(device, target, write.value, ctx)
            else:  # a command's Result
                self.refuse(NotWritable.status, where, f"{write.metric.name} is read-only")

    def _context(self, device: Device) -> WriteContext:
        return WriteContext(ORIGIN, user=None, role=self.tree.access.mqtt_role(device.name))

    def _no_role(self, device: Device) -> AccessDenied | None:
        access = self.tree.access
        if access.enabled and access.mqtt_role(device.name) is None:
            return AccessDenied(
                f"Sparkplug requests to {device.name} have no role while access control is on "
                "(mapping: mqtt.writer_role, or the gateway file's access.mqtt_writer_role)"
            )
        return None

    def _write(self, device: Device, metric: VariableMetric, value: Any, ctx: WriteContext) -> None:
        node = metric.node
        try:
            if node.internal or not node.definition.writable:
                raise NotWritable(f"{node.full_path} is read-only")
            if not metric.writable:
                raise AccessDenied(
                    f"writes over MQTT and Sparkplug are not enabled for {node.full_path} "
                    "(mapping: mqtt.writable: true)"
                )
            no_role = self._no_role(device)
            if no_role is not None:
                raise no_role
            try:
                self.writes[device.name].put_nowait(_Write(metric, value))
            except asyncio.QueueFull:
                raise TooManyWrites(
                    f"{self.max_pending} requests to {device.name} are already waiting; try again"
                ) from None
        except RequestError as exc:
            device.machine.audit_write(node, node.sample.value, value, ctx, exc)
            self.refuse(exc.status, f"DCMD to {device.name}", f"{node.path}: {exc.reason}")
            self._show(self.outcomes.show_variable(metric))

    def _call(self, device: Device, command: CommandMetric, value: Any, ctx: WriteContext) -> None:
        method = command.method
        args: list[Any] = []
        try:
            if not command.enabled:
                raise AccessDenied(
                    f"commands over MQTT and Sparkplug are not enabled for {device.name} "
                    "(mapping: mqtt: {commands: true})"
                )
            no_role = self._no_role(device)
            if no_role is not None:
                raise no_role
            args = command.arguments(value)
            try:
                self.calls[device.name].put_nowait(_Call(command, args))
            except asyncio.QueueFull:
                raise TooManyWrites(
                    f"{self.max_pending} requests to {device.name} are already waiting; try again"
                ) from None
        except RequestError as exc:
            device.machine.audit_call(method, args, ctx, exc)
            self._end_command(device, command, exc)

    def refuse(self, kind: str, where: str, reason: str) -> None:
        """Count a refusal by kind and log it (within the quota)."""
        self.refusals[kind] += 1
        if self._quota.allow():
            log.info("Sparkplug %s refused (%s): %s", where, kind, reason[:300])

    def _show(self, shown: Awaitable[None]) -> None:
        task = asyncio.ensure_future(shown)
        self._shown.add(task)
        task.add_done_callback(self._shown_done)

    def _shown_done(self, task: asyncio.Future[None]) -> None:
        self._shown.discard(task)
        if not task.cancelled() and task.exception() is not None:
            log.error("Sparkplug: showing an outcome failed", exc_info=task.exception())

    def _end_command(
        self, device: Device, command: CommandMetric, error: RequestError | None, result: str = ""
    ) -> None:
        command.result = f"Good: {result}" if error is None else f"{error.status}: {error.reason}"
        command.result_ts = now_ms()
        if error is not None:
            self.refuse(error.status, f"DCMD to {device.name}", f"{command.execute}: {error.reason}")
        self._show(self.outcomes.show_command(device, command))

    # --- workers ------------------------------------------------------------------------------

    async def write_worker(self, name: str) -> None:
        """Carry out one machine's queued writes, in order, until cancelled."""
        queue = self.writes[name]
        device = self.devices[name]
        machine = device.machine
        while True:
            job = await queue.get()
            node = job.metric.node
            before = node.sample
            try:
                await machine.write_node(node, job.value, self._context(device))
            except RequestError as exc:
                self.refuse(exc.status, f"DCMD to {name}", f"{node.path}: {exc.reason}")
            except Exception as exc:  # a bug below must not end the writes of this machine
                log.exception("Sparkplug write to %s failed unexpectedly", node.full_path)
                self.refuse(WriteError.status, f"DCMD to {name}", f"{node.path}: internal error: {exc}")
            else:
                self.accepted += 1
                log.info("Sparkplug write: %s = %r", node.full_path, job.value)
            if node.sample is before:  # nothing new arrives by the tree: say what it still holds
                await self.outcomes.show_variable(job.metric)

    async def call_worker(self, name: str) -> None:
        """Carry out one machine's queued commands, up to MAX_RUNNING at once, until cancelled."""
        await carry_out(
            self.calls[name],
            lambda job: self._run(name, job),
            lambda job: f"sparkplug:command:{name}:{job.command.method.name}",
        )

    async def _run(self, name: str, job: _Call) -> None:
        device = self.devices[name]
        method = job.command.method
        try:
            outputs = await device.machine.call_method(method, job.args, self._context(device))
        except RequestError as exc:
            self._end_command(device, job.command, exc)
            return
        except Exception as exc:  # a bug below must not end the commands of this machine
            log.exception("Sparkplug command %s/%s failed unexpectedly", name, method.name)
            self._end_command(device, job.command, CallError(f"internal error: {exc}"))
            return
        self.accepted += 1
        result = str(outputs[0]) if outputs else ""
        log.info("Sparkplug command %s/%s: %s", name, method.name, result)
        self._end_command(device, job.command, None, result)

"""The variable tree: one node per mapped variable, holding its latest Sample.

The tree is built from the model's own definitions (gateway/model/definitions.py),
which the configuration makes from the mapping files; it knows nothing of YAML,
pydantic or drivers. Sources push raw controller values in through
`Machine.ingest`; scaling and deadband are applied here, once, and accepted
changes go to the change hub. Writes from any sink come back through
`Machine.write`, which checks access, the caller's role, type and range and
undoes the scaling before asking the source; the source's read-back of the
written variable is in the tree before the write is answered (read-your-writes).
Method calls go through `Machine.call_method`, which checks the role. Both are
audited (`VariableTree.audit_sinks`), refusals included. Nothing else talks to a
controller.
"""

from __future__ import annotations

import time
from collections.abc import Awaitable, Callable, Iterable, Iterator, Sequence
from datetime import datetime
from typing import Any, Protocol

from gateway.errors import (
    CallError,
    ControllerUnavailable,
    NotWritable,
    OutOfRange,
    RequestError,
    UnknownVariable,
    WriteError,
)
from gateway.model.access import AccessPolicy
from gateway.model.audit import AuditEntry, as_text
from gateway.model.context import WriteContext
from gateway.model.definitions import MachineDefinition, VariableDefinition
from gateway.model.events import EventBus
from gateway.model.hub import ChangeHub
from gateway.model.methods import Method
from gateway.model.sample import ReadBack, Sample, utcnow
from gateway.model.status import MachineStatus
from gateway.model.types import DataType, TypeSpec, check_int_bounds, coerce

__all__ = ["Machine", "VariableNode", "VariableTree", "WriteContext", "WriteHook", "Writer"]


class Writer(Protocol):
    """What the tree needs from a source to carry out a write: the raw value, to the controller.

    It answers with the controller's value read back after the write (a `ReadBack`),
    or None when it could not read it back; the tree takes the reading in before
    the write is answered, so that the caller reads what it wrote.
    """

    async def write(self, node: VariableNode, raw: Any) -> ReadBack | None: ...


# A write hook sees every write before it reaches the source, and may refuse it
# (role checks, audit). It receives the node, the engineering value and the caller.
WriteHook = Callable[["VariableNode", Any, WriteContext], Awaitable[None]]


class VariableNode:
    """A variable in the tree. Identity-hashed, so sinks can key their caches on it."""

    __slots__ = (
        "_deadband",
        "_gain",
        "_hold",
        "_offset",
        "_published",
        "_round",
        "_scaled",
        "definition",
        "internal",
        "machine",
        "path",
        "sample",
    )

    def __init__(
        self,
        machine: Machine,
        definition: VariableDefinition,
        *,
        internal: bool = False,
        waiting: Sample | None = None,
    ) -> None:
        self.machine = machine
        self.definition = definition
        self.path = definition.path
        self.internal = internal
        # Until the first value: `waiting`, one frozen Sample that a machine's variables of a type share.
        self.sample: Sample = waiting or waiting_for_data(definition.type, utcnow())
        self._published: Any = None
        self._gain = definition.gain
        self._offset = definition.offset
        self._scaled = definition.scaled
        self._deadband = definition.deadband
        self._round = definition.type.is_integer
        # After a write's read-back: (its source time, until when older notifications are dropped).
        self._hold: tuple[datetime, float] | None = None

    def __repr__(self) -> str:
        return f"<VariableNode {self.machine.name}/{self.path}>"

    @property
    def type(self) -> TypeSpec:
        return self.definition.type

    @property
    def full_path(self) -> str:
        return f"{self.machine.name}/{self.path}"

    # --- scaling ---------------------------------------------------------------------------

    def to_engineering(self, raw: Any) -> Any:
        if not self._scaled or raw is None:
            return raw
        gain, offset = self._gain, self._offset
        if isinstance(raw, list):
            values = [v * gain + offset for v in raw]
            return [round(v) for v in values] if self._round else values
        value = raw * gain + offset
        return round(value) if self._round else value

    def to_raw(self, value: Any) -> Any:
        """Engineering value to the controller's value and type (the inverse of scaling)."""
        raw_type = self.definition.raw_type
        if self._scaled:
            gain, offset = self._gain, self._offset
            if isinstance(value, list):
                value = [(v - offset) / gain for v in value]
            else:
                value = (value - offset) / gain
        if raw_type.is_integer:
            items = value if isinstance(value, list) else [value]
            rounded = [round(v) for v in items]
            for v in rounded:
                check_int_bounds(raw_type.base, v)
            return rounded if isinstance(value, list) else rounded[0]
        if raw_type.base in (DataType.FLOAT, DataType.DOUBLE):
            return [float(v) for v in value] if isinstance(value, list) else float(value)
        return value

    # --- deadband --------------------------------------------------------------------------

    def _changed(self, value: Any) -> bool:
        last = self._published
        if self._deadband <= 0.0 or last is None:
            return bool(value != last)
        if isinstance(value, list):
            if not isinstance(last, list) or len(value) != len(last):
                return True
            db = self._deadband
            return any(abs(a - b) > db for a, b in zip(value, last, strict=True))
        return bool(abs(value - last) > self._deadband)

    def check_range(self, value: Any) -> None:
        rng = self.definition.range
        if rng is None:
            return
        for v in value if isinstance(value, list) else (value,):
            if not rng.min <= v <= rng.max:
                raise OutOfRange(f"{v} is outside the range {rng.min:g}..{rng.max:g} of {self.full_path}")


class Machine:
    """One machine's part of the tree: its variables, its status, and the way back to its controller."""

    def __init__(self, tree: VariableTree, definition: MachineDefinition) -> None:
        self.tree = tree
        self.name = definition.name
        self.definition = definition
        self.nodes: dict[str, VariableNode] = {}
        self.writer: Writer | None = None
        self.methods: dict[tuple[str, str], Method] = {}
        self._hub = tree.hub
        self._last_change_push = 0.0
        # Samples published to the hub (/metrics: changes/s), counted here, not by a sink. It moves whenever a
        # node's sample is replaced: the console's live pages look only at machines whose count moved.
        self.changes = 0
        now = utcnow()
        waiting: dict[TypeSpec, Sample] = {}  # scalars only: an array's empty list is its own
        for variable in definition.variables:
            if variable.path in self.nodes:
                raise ValueError(f"{self.name}: variable {variable.path!r} defined twice")
            sample = waiting.get(variable.type)
            if sample is None and not variable.type.array:
                sample = waiting[variable.type] = waiting_for_data(variable.type, now)
            self.nodes[variable.path] = VariableNode(self, variable, waiting=sample)
        self.status: MachineStatus[VariableNode] = MachineStatus(self, definition.endpoint)

    def __repr__(self) -> str:
        return f"<Machine {self.name}>"

    @property
    def served(self) -> bool:
        """False while another shard serves the machine (`shard: lease`, gateway/sources/leased.py): the
        MQTT and Sparkplug faces then publish nothing of it (`VariableTree.standby`), so its standby values
        never overwrite the serving shard's; OPC UA shows it, Bad, with its ServiceLevel low."""
        return self.name not in self.tree.standby

    @served.setter
    def served(self, served: bool) -> None:
        if served:
            self.tree.standby.discard(self.name)
        else:
            self.tree.standby.add(self.name)

    @property
    def mapped(self) -> Iterator[VariableNode]:
        return (n for n in self.nodes.values() if not n.internal)

    def add_internal(self, path: str, type_name: str, description: str, value: Any) -> VariableNode:
        """A variable the gateway itself owns (status, jobs), published like any other."""
        definition = VariableDefinition(path, TypeSpec.parse(type_name), description=description)
        node = VariableNode(self, definition, internal=True)
        self.nodes[path] = node
        self.set_internal(node, value)
        return node

    def add_method(self, method: Method) -> None:
        """Register an operation (see gateway/model/methods.py); sinks expose it."""
        key = (method.object, method.name)
        if key in self.methods:
            raise ValueError(f"{self.name} already has {method.object}.{method.name}")
        self.methods[key] = method

    def set_internal(self, node: VariableNode, value: Any) -> None:
        if node._published == value and node.sample.good:
            return
        sample = Sample(value, utcnow())
        node.sample = sample
        node._published = value
        self._hub.publish(node, sample)
        self.changes += 1

    # --- from the source -------------------------------------------------------------------

    def ingest(
        self, node: VariableNode, raw: Any, source_ts: datetime, status: str = "Good", reason: str = ""
    ) -> None:
        """A value (or a bad status) reported by the controller for one variable."""
        if status.startswith("Bad"):
            self._publish_status(node, status, reason, source_ts)
            return
        hold = node._hold
        if hold is not None and _held_back(node, hold, source_ts):
            return
        try:
            value = node.to_engineering(raw)
        except TypeError:
            self._publish_status(
                node,
                "BadTypeMismatch",
                f"controller sent {type(raw).__name__}, mapping says {node.type}",
                source_ts,
            )
            return
        prev = node.sample
        if prev.status == status and not node._changed(value):
            return
        sample = Sample(value, source_ts, status, reason)
        node.sample = sample
        node._published = value
        self._hub.publish(node, sample)
        self.changes += 1
        now = time.monotonic()
        if now - self._last_change_push >= 1.0:
            self._last_change_push = now
            self.status.changed(source_ts)

    def confirm(self, node: VariableNode, reading: ReadBack) -> None:
        """The controller's value of `node`, read back right after a write: in the tree at once.

        So the writer (and every sink) sees the written value when the write is
        answered, not 20-100 ms later when the subscription reports it. For
        `reading.hold` seconds a notification older than the reading (one already
        on its way when the write was made) does not replace it. A Bad read-back,
        or one older than what the tree already holds, changes nothing.
        """
        if reading.status.startswith("Bad"):
            return
        current = node.sample
        if current.good and _before(reading.source_ts, current.source_ts):
            return
        node._hold = None
        self.ingest(node, reading.raw, reading.source_ts, reading.status, reading.reason)
        node._hold = (reading.source_ts, time.monotonic() + reading.hold)

    def invalidate(self, status: str, reason: str) -> None:
        """Every mapped variable turns bad at once, e.g. when the controller is unreachable."""
        now = utcnow()
        for node in self.mapped:
            self._publish_status(node, status, reason, now)

    def _publish_status(self, node: VariableNode, status: str, reason: str, ts: datetime) -> None:
        prev = node.sample
        if prev.status == status and prev.reason == reason:
            return
        sample = Sample(prev.value, ts, status, reason)
        node.sample = sample
        self._hub.publish(node, sample)
        self.changes += 1

    # --- from a sink -----------------------------------------------------------------------

    async def write(self, path: str, value: Any, ctx: WriteContext) -> None:
        """Check and carry out a write. Raises a RequestError with the reason if refused."""
        node = self.nodes.get(path)
        if node is None:
            raise UnknownVariable(f"{self.name} has no variable {path!r}")
        await self.write_node(node, value, ctx)

    def write_role(self, node: VariableNode) -> str | None:
        """The lowest role that may write `node`: its own, else the machine's default, else the gateway's."""
        return node.definition.role or self.definition.write_role or self.tree.access.default_write_role

    async def write_node(
        self, node: VariableNode, value: Any, ctx: WriteContext, *, check: Callable[[], None] | None = None
    ) -> None:
        """Check, authorise, carry out and audit one write; raises a RequestError if refused.

        `check` is the sink's own check of the request (OPC UA's strict Variant
        types, say): it runs after the role check and raises a RequestError to refuse,
        so that its refusals are audited like any other. When it returns, the tree
        holds the value the controller reported back (if the source could read it).
        """
        started = time.monotonic()
        at = utcnow()
        old = node.sample.value
        try:
            await self._write_node(node, value, ctx, check)
        except RequestError as exc:
            self.audit_write(node, old, value, ctx, exc, at, started)
            raise
        except Exception as exc:
            self.audit_write(node, old, value, ctx, WriteError(f"internal error: {exc}"), at, started)
            raise
        self.audit_write(node, old, value, ctx, None, at, started)

    def audit_write(
        self,
        node: VariableNode,
        old: Any,
        value: Any,
        ctx: WriteContext,
        error: RequestError | None,
        at: datetime | None = None,
        started: float | None = None,
    ) -> None:
        """Record a write in the audit trail; sinks call it for requests they refuse before `write_node`."""
        self.audit(
            "write", node.path, ctx, old=as_text(old), new=as_text(value), error=error, at=at, started=started
        )

    def audit(
        self,
        kind: str,
        target: str,
        ctx: WriteContext,
        *,
        old: str | None = None,
        new: str | None = None,
        error: RequestError | None = None,
        at: datetime | None = None,
        started: float | None = None,
    ) -> None:
        """Record an action on this machine (acknowledge, confirm, …): `old`/`new` are JSON text (as_text)."""
        if not self.tree.audit_sinks:
            return
        duration = 0.0 if started is None else time.monotonic() - started
        self.tree.audit(
            AuditEntry(
                at or utcnow(),
                kind,
                self.name,
                target,
                ctx.origin,
                ctx.user,
                self.tree.access.role_of(ctx),
                old,
                new,
                "Good" if error is None else error.status,
                "" if error is None else error.reason,
                duration,
            )
        )

    async def call_method(
        self,
        method: Method,
        args: Sequence[Any],
        ctx: WriteContext,
        *,
        check: Callable[[], None] | None = None,
    ) -> Sequence[Any]:
        """Authorise (Method.role), run and audit one call; every sink calls methods through here.

        Raises AccessDenied (BadUserAccessDenied) for a role below the method's, the
        method's own RequestError otherwise. `check` is as for `write_node`.
        """
        started = time.monotonic()
        at = utcnow()
        access = self.tree.access
        try:
            what = f"call {self.name}/{method.object}.{method.name}"
            access.require(access.role_of(ctx), method.role, what)
            if check is not None:
                check()
            outputs = await method.call(ctx, args)
        except RequestError as exc:
            self.audit_call(method, args, ctx, exc, at, started)
            raise
        except Exception as exc:
            self.audit_call(method, args, ctx, CallError(f"internal error: {exc}"), at, started)
            raise
        self.audit_call(method, args, ctx, None, at, started)
        return outputs

    def audit_call(
        self,
        method: Method,
        args: Sequence[Any],
        ctx: WriteContext,
        error: RequestError | None,
        at: datetime | None = None,
        started: float | None = None,
    ) -> None:
        target = f"{method.object}.{method.name}"
        self.audit("call", target, ctx, new=as_text(list(args)), error=error, at=at, started=started)

    async def _write_node(
        self, node: VariableNode, value: Any, ctx: WriteContext, check: Callable[[], None] | None
    ) -> None:
        if node.internal or not node.definition.writable:
            raise NotWritable(f"{node.full_path} is read-only")
        access = self.tree.access
        access.require(access.role_of(ctx), self.write_role(node), f"write {node.full_path}")
        if check is not None:
            check()
        engineering = coerce(node.type, value)
        node.check_range(engineering)
        for hook in self.tree.write_hooks:
            await hook(node, engineering, ctx)
        raw = node.to_raw(engineering)
        writer = self.writer
        if writer is None:
            raise ControllerUnavailable(f"{self.name} has no controller connection")
        reading = await writer.write(node, raw)
        if reading is not None:
            self.confirm(node, reading)


def waiting_for_data(spec: TypeSpec, now: datetime) -> Sample:
    """A variable's sample before its first value: the type's neutral value, BadWaitingForInitialData."""
    return Sample(spec.default(), now, "BadWaitingForInitialData", "no value yet")


def _before(a: datetime, b: datetime) -> bool:
    """Whether source time `a` is earlier than `b` (False when the two cannot be compared)."""
    try:
        return a < b
    except TypeError:  # one naive, one aware: a driver's quirk, not a reason to drop a value
        return False


def _held_back(node: VariableNode, hold: tuple[datetime, float], source_ts: datetime) -> bool:
    """After a write's read-back: whether this notification is older than the reading (and dropped).

    The hold ends with the first notification that is not older, or when its time is up,
    so a controller whose clock steps back cannot freeze the variable.
    """
    since, until = hold
    if _before(source_ts, since) and time.monotonic() < until:
        return True
    node._hold = None
    return False


class VariableTree:
    """All machines, and the hub their changes go through."""

    def __init__(self, machines: Iterable[MachineDefinition] = ()) -> None:
        self.hub: ChangeHub[VariableNode] = ChangeHub()
        self.events = EventBus()
        self.machines: dict[str, Machine] = {}
        self.write_hooks: list[WriteHook] = []
        self.access = AccessPolicy()
        # Machines another shard serves (Machine.served): one set, read on the MQTT faces' hot paths.
        self.standby: set[str] = set()
        # Every write and call ends up here (gateway/audit/trail.py logs and stores them); never blocks.
        self.audit_sinks: list[Callable[[AuditEntry], None]] = []
        for definition in machines:
            self.add_machine(definition)

    def audit(self, entry: AuditEntry) -> None:
        for sink in self.audit_sinks:
            sink(entry)

    def add_machine(self, definition: MachineDefinition) -> Machine:
        if definition.name in self.machines:
            raise ValueError(f"machine {definition.name!r} defined twice")
        machine = Machine(self, definition)
        self.machines[definition.name] = machine
        return machine

    def nodes(self) -> Iterator[VariableNode]:
        for machine in self.machines.values():
            yield from machine.nodes.values()

    def find(self, machine: str, path: str) -> VariableNode:
        try:
            return self.machines[machine].nodes[path]
        except KeyError:
            raise UnknownVariable(f"no variable {machine}/{path}") from None

    async def write(self, machine: str, path: str, value: Any, ctx: WriteContext) -> None:
        m = self.machines.get(machine)
        if m is None:
            raise UnknownVariable(f"no machine {machine!r}")
        await m.write(path, value, ctx)

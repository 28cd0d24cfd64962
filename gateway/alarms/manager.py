"""One machine's alarms: watch the controller's active list, keep the occurrences, honour acknowledgements.

The manager follows the mapped alarm variables through the change hub. Each
time the list changes it compares it with the active occurrences (`diff`) and
records the raises and clears in the store, in one transaction, before anyone
hears of them. Acknowledge and Confirm (from any sink, with the caller's role
checked) are recorded the same way, and go to the audit trail like writes and
calls (kind "acknowledge"/"confirm", target `Alarms/<id>#<occurrence>`), refusals too. Listeners (the OPC UA
conditions) and the event bus (MQTT: `alarms/events`, and the retained `alarms/active` list) learn
of every change afterwards, in order.

A controller that drops does not clear anything: the occurrences are kept as
they were and their quality turns uncertain. When the list can be read again,
it is reconciled like any other change: what is gone is cleared then.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import time
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import replace
from datetime import datetime
from typing import TYPE_CHECKING, Any, TypeVar

from gateway.alarms.config import AlarmsConfig
from gateway.alarms.records import AlarmChange, AlarmRecord, Kind, Quality
from gateway.alarms.sources import Reading, diff, source_for
from gateway.alarms.store import AlarmHistory
from gateway.errors import AlarmStoreError, CallError, InvalidState, RequestError
from gateway.model.audit import as_text
from gateway.model.context import WriteContext
from gateway.model.events import Event
from gateway.model.sample import utcnow

if TYPE_CHECKING:
    from gateway.model.tree import Machine

log = logging.getLogger("gateway.alarms")

T = TypeVar("T")
Listener = Callable[[AlarmChange], Awaitable[None]]
DbCall = Callable[..., Awaitable[Any]]
Check = Callable[[], None]  # a sink's own check of a request: raises a RequestError to refuse it

SETTLE = 0.5  # s to wait for the other arrays when one of them has changed length alone
EVENTS = "alarms/events"
OBJECT = "Alarms"  # audit targets: Alarms/<alarm id>#<occurrence>
ACTIVE = "alarms/active"


class UnknownAlarm(CallError):
    status = "BadNodeIdUnknown"


class AlreadyAcknowledged(CallError):
    status = "BadConditionBranchAlreadyAcked"


class AlreadyConfirmed(CallError):
    status = "BadConditionBranchAlreadyConfirmed"


def who(ctx: WriteContext) -> str:
    """The name recorded for an acknowledgement: the user, or how an anonymous caller came in."""
    return ctx.user or f"anonymous ({ctx.origin})"


SERVED_PATH = "Status/Served"  # a lease-served machine's (gateway/sources/leased.py)


def _step(old: AlarmRecord, new: AlarmRecord) -> Kind:
    """The furthest step an occurrence took between two of its states: cleared, acknowledged, confirmed."""
    if old.active and not new.active:
        return Kind.CLEARED
    if not old.acked and new.acked:
        return Kind.ACKNOWLEDGED
    return Kind.CONFIRMED


class AlarmManager:
    """The alarms of one machine with an `alarms:` section."""

    def __init__(
        self,
        machine: Machine,
        config: AlarmsConfig,
        store: AlarmHistory,
        db: DbCall,
        variables: Sequence[Any] = (),
    ) -> None:
        self.machine = machine
        self.config = config
        self.store = store
        self.source = source_for(machine, config, variables)  # the mapping's variables: a source's defaults
        self.records: dict[int, AlarmRecord] = {}  # retained occurrences by number
        self.quality = Quality.UNCERTAIN
        self.reason = "waiting for the controller's alarm list"
        self._db = db
        self._listeners: list[Listener] = []
        self._lock = asyncio.Lock()

    @property
    def name(self) -> str:
        return self.machine.name

    def load(self, records: list[AlarmRecord]) -> None:
        """The occurrences a previous run left retained; uncertain until the controller's list is read."""
        self.records = {r.occurrence: replace(r, quality=self.quality, reason=self.reason) for r in records}

    def listen(self, listener: Listener) -> None:
        self._listeners.append(listener)

    def retained(self) -> list[AlarmRecord]:
        return sorted(self.records.values(), key=lambda r: r.occurrence)

    # --- following the controller ----------------------------------------------------------------

    async def run(self) -> None:
        """Follow the alarm variables until cancelled."""
        hub = self.machine.tree.hub
        sub = hub.subscribe(f"alarms:{self.name}")
        loop = asyncio.get_running_loop()
        # shard: lease (gateway/sources/leased.py): the machine's lease arriving here, after another shard
        # served it, is the moment to take over the alarms as that shard left them in the shared history.
        served = self.machine.nodes.get(SERVED_PATH)
        try:
            self.publish_active()
            await self.apply(self.source.read())
            watched = self.source.nodes
            while True:
                batch = await sub.next_batch()
                if served is not None and any(n is served and s.value is True for n, s in batch):
                    await self.take_over()
                if not any(node in watched for node, _ in batch):
                    continue
                reading = self.source.read()
                deadline = loop.time() + SETTLE
                while not reading.consistent and (left := deadline - loop.time()) > 0:
                    try:
                        await asyncio.wait_for(sub.next_batch(), left)
                    except TimeoutError:
                        break
                    reading = self.source.read()
                await self.apply(reading)
        finally:
            sub.close()

    async def take_over(self) -> None:
        """This process serves the machine from now on (shard: lease). Another shard may have raised,
        cleared, acknowledged or confirmed its alarms since this one loaded them: the shared history's
        retained occurrences replace what it holds. The listeners (OPC UA conditions) hear of each
        difference; the event stream does not (the other shard published those events when they
        happened), the retained list does."""
        async with self._lock:
            try:
                fresh = {r.occurrence: r for r in await self._db(self.store.retained, self.name)}
                gone = [n for n in self.records if n not in fresh]
                ended: dict[int, AlarmRecord] = {}
                if gone:
                    since = min(self.records[n].raised_at for n in gone)
                    read = functools.partial(self.store.history, self.name, since, limit=10_000)
                    ended = {r.occurrence: r for r in await self._db(read) if r.occurrence in gone}
            except AlarmStoreError as exc:
                log.error("%s: the alarm history cannot be read at the takeover (kept as loaded): %s",
                          self.name, exc)  # fmt: skip
                return
            now = utcnow()
            changes: list[AlarmChange] = []
            for number in gone:  # ended on the other shard: cleared and acknowledged (and confirmed)
                old = self.records[number]
                done = ended.get(number) or replace(
                    old, cleared_at=old.cleared_at or now, acked_at=old.acked_at or now,
                    confirmed_at=old.confirmed_at or now,
                )  # fmt: skip
                changes.append(self._put(_step(old, done), self._as_here(done), now))
            for number, record in fresh.items():
                held = self.records.get(number)
                if held is None:  # raised on the other shard after this one loaded the history
                    changes.append(self._put(Kind.RAISED, self._as_here(record), record.raised_at))
                elif (held.cleared_at, held.acked_at, held.confirmed_at) != (
                    record.cleared_at, record.acked_at, record.confirmed_at,
                ):  # fmt: skip
                    changes.append(self._put(_step(held, record), self._as_here(record), now))
            if changes:
                log.info("%s: taken over: %d alarm change(s) made on another shard", self.name, len(changes))
            await self._emit(changes, events=False)

    def _as_here(self, record: AlarmRecord) -> AlarmRecord:
        return replace(record, quality=self.quality, reason=self.reason)

    async def apply(self, reading: Reading) -> None:
        """One look at the controller's list (or at its absence)."""
        async with self._lock:
            if reading.alarms is None:
                await self._uncertain(reading.reason)
                return
            active = {r.id: r for r in self.records.values() if r.active}
            raised, cleared = diff(active, reading.alarms)
            was_uncertain = self.quality is not Quality.GOOD
            if not raised and not cleared and not was_uncertain:
                return
            confirm = self.config.confirm
            ts = reading.ts
            gone = [
                replace(r, cleared_at=max(ts, r.raised_at), quality=Quality.GOOD, reason="") for r in cleared
            ]
            severities = [self.config.severity_of(e.severity_class) for e in raised]
            numbers: list[int] = []
            if raised or gone:
                try:
                    numbers = await self._db(
                        self.store.apply,
                        self.name,
                        list(zip(raised, severities, strict=True)),
                        [(r.occurrence, r.cleared_at, r.retained(confirm)) for r in gone],
                        ts,
                    )
                except AlarmStoreError as exc:
                    log.error("%s: alarms not recorded (kept as they were): %s", self.name, exc)
                    return
            changes: list[AlarmChange] = []
            for record in gone:
                changes.append(self._put(Kind.CLEARED, record, record.cleared_at or ts))
            self.quality, self.reason = Quality.GOOD, ""
            for number, entry, severity in zip(numbers, raised, severities, strict=True):
                record = AlarmRecord(
                    occurrence=number,
                    machine=self.name,
                    id=entry.id,
                    text=entry.text,
                    severity=severity,
                    severity_class=entry.severity_class,
                    raised_at=ts,
                    parameters=dict(entry.parameters),
                )
                changes.append(self._put(Kind.RAISED, record, ts))
            if was_uncertain:
                now = utcnow()
                for record in list(self.records.values()):
                    if record.quality is not Quality.GOOD:
                        changes.append(
                            self._put(Kind.QUALITY, replace(record, quality=Quality.GOOD, reason=""), now)
                        )
            for change in changes:
                if change.kind is Kind.RAISED:
                    log.warning("%s: alarm %s raised: %s", self.name, change.record.id, change.record.text)
                elif change.kind is Kind.CLEARED:
                    log.info("%s: alarm %s cleared", self.name, change.record.id)
            await self._emit(changes)

    async def _uncertain(self, reason: str) -> None:
        if self.quality is Quality.UNCERTAIN:  # already told (a new retry reason is no news for alarms)
            return
        self.quality, self.reason = Quality.UNCERTAIN, reason
        now = utcnow()
        changes = [
            self._put(Kind.QUALITY, replace(r, quality=Quality.UNCERTAIN, reason=reason), now)
            for r in list(self.records.values())
        ]
        if changes:
            log.info(
                "%s: %d alarm(s) kept as they were while the controller is away: %s",
                self.name,
                len(changes),
                reason,
            )
        await self._emit(changes)

    # --- acknowledge and confirm -----------------------------------------------------------------

    async def acknowledge(
        self, occurrence: int, ctx: WriteContext, comment: str = "", *, check: Check | None = None
    ) -> AlarmRecord:
        """Record that `ctx`'s caller has seen the alarm. Raises a RequestError with the OPC UA status.

        `check` is the sink's own check of the request (OPC UA: a known EventId): it runs
        after the role check and raises a RequestError to refuse, so its refusals are audited too.
        """
        return await self._audited("acknowledge", occurrence, ctx, comment, check, self._acknowledge)

    async def confirm(
        self, occurrence: int, ctx: WriteContext, comment: str = "", *, check: Check | None = None
    ) -> AlarmRecord:
        """Record that the cause has been dealt with (after the acknowledgement); `check` as above."""
        return await self._audited("confirm", occurrence, ctx, comment, check, self._confirm)

    async def _audited(
        self,
        kind: str,
        occurrence: int,
        ctx: WriteContext,
        comment: str,
        check: Check | None,
        action: Callable[[int, WriteContext, str, Check | None], Awaitable[AlarmRecord]],
    ) -> AlarmRecord:
        """Carry out an acknowledge or confirm and audit it, refusals and failures included."""
        started, at = time.monotonic(), utcnow()
        known = self.records.get(occurrence)  # read first: an alarm that ends with this call leaves `records`
        target = f"{OBJECT}/{known.id if known is not None else ''}#{occurrence}"

        def audit(error: RequestError | None) -> None:
            self.machine.audit(kind, target, ctx, new=as_text([comment]), error=error, at=at, started=started)

        try:
            record = await action(occurrence, ctx, comment, check)
        except RequestError as exc:
            audit(exc)
            raise
        except Exception as exc:
            audit(CallError(f"internal error: {exc}"))
            raise
        audit(None)
        return record

    async def _acknowledge(
        self, occurrence: int, ctx: WriteContext, comment: str, check: Check | None
    ) -> AlarmRecord:
        self.machine.tree.access.require(ctx.role, self.config.acknowledge_role, "acknowledge alarms")
        if check is not None:
            check()
        async with self._lock:
            record = self._get(occurrence)
            if record.acked:
                raise AlreadyAcknowledged(
                    f"alarm {record.id} (occurrence {occurrence}) is already acknowledged"
                )
            now, user = utcnow(), who(ctx)
            new = replace(record, acked_at=now, acked_by=user, ack_comment=comment)
            retained = new.retained(self.config.confirm)
            if not await self._mark(self.store.acknowledge, occurrence, now, user, comment, retained):
                raise AlreadyAcknowledged(
                    f"alarm {record.id} (occurrence {occurrence}) is already acknowledged"
                )
            log.info(
                "%s: alarm %s acknowledged by %s%s",
                self.name,
                record.id,
                user,
                f": {comment}" if comment else "",
            )
            await self._emit([self._put(Kind.ACKNOWLEDGED, new, now, user, comment)])
            return new

    async def _confirm(
        self, occurrence: int, ctx: WriteContext, comment: str, check: Check | None
    ) -> AlarmRecord:
        self.machine.tree.access.require(ctx.role, self.config.acknowledge_role, "confirm alarms")
        if check is not None:
            check()
        async with self._lock:
            record = self._get(occurrence)
            if record.confirmed:
                raise AlreadyConfirmed(f"alarm {record.id} (occurrence {occurrence}) is already confirmed")
            if not record.acked:
                raise InvalidState(f"alarm {record.id} (occurrence {occurrence}) must be acknowledged first")
            now, user = utcnow(), who(ctx)
            new = replace(record, confirmed_at=now, confirmed_by=user, confirm_comment=comment)
            retained = new.retained(self.config.confirm)
            if not await self._mark(self.store.confirm, occurrence, now, user, comment, retained):
                raise AlreadyConfirmed(f"alarm {record.id} (occurrence {occurrence}) is already confirmed")
            log.info("%s: alarm %s confirmed by %s", self.name, record.id, user)
            await self._emit([self._put(Kind.CONFIRMED, new, now, user, comment)])
            return new

    def _get(self, occurrence: int) -> AlarmRecord:
        record = self.records.get(occurrence)
        if record is None:
            raise UnknownAlarm(f"{self.name} lists no alarm occurrence {occurrence} (it may have ended)")
        return record

    async def _mark(self, call: Callable[..., bool], *args: Any) -> bool:
        try:
            return bool(await self._db(call, *args))
        except AlarmStoreError as exc:
            raise CallError(f"the alarm history cannot record it: {exc}") from None

    # --- state and telling others ----------------------------------------------------------------

    def _put(
        self, kind: Kind, record: AlarmRecord, ts: datetime, user: str = "", comment: str = ""
    ) -> AlarmChange:
        retained = record.retained(self.config.confirm)
        if retained:
            self.records[record.occurrence] = record
        else:
            self.records.pop(record.occurrence, None)
        return AlarmChange(kind, record, ts, retained, user, comment)

    async def _emit(self, changes: list[AlarmChange], *, events: bool = True) -> None:
        if not changes:
            return
        bus = self.machine.tree.events
        for change in changes:
            if events and change.kind is not Kind.QUALITY:
                payload = {"event": change.kind.value, **change.record.as_dict()}
                if change.user:
                    payload["user"] = change.user
                if change.comment:
                    payload["comment"] = change.comment
                bus.publish(Event(self.name, EVENTS, payload, retain=False, ts=change.ts))
        self.publish_active()
        for change in changes:
            for listener in self._listeners:
                try:
                    await listener(change)
                except Exception:  # a sink's trouble must not stop the alarms of the others
                    log.exception("%s: an alarm listener failed on %s", self.name, change.kind.value)

    def publish_active(self) -> None:
        """The retained list on the event bus (MQTT `alarms/active`, retained)."""
        payload = [r.as_dict() for r in self.retained()]
        self.machine.tree.events.publish(Event(self.name, ACTIVE, payload, retain=True))

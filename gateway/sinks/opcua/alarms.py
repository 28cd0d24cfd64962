"""Machine alarms in the OPC UA server: condition nodes, events, Acknowledge, Confirm and ConditionRefresh.

Each machine with alarms is an event notifier (EventNotifier SubscribeToEvents,
and the Server object HasNotifier it), so a client may subscribe to events on the
Server object, as most SCADA systems do, or on the machine alone. Every alarm
occurrence is a condition node `<machine>/Alarms/<occurrence>` of type
AlarmConditionType while it is retained; each transition (raised, cleared,
acknowledged, confirmed, quality) is reported as an event through both notifiers,
with the same EventId. When an occurrence ends (Retain false) its node goes.

Clients acknowledge and confirm by calling the standard methods
AcknowledgeableConditionType.Acknowledge/Confirm (i=9111/9113) on the condition
node with an EventId the condition reported and a comment; the alarm manager
checks the caller's role, records it, and puts it in the audit trail (refusals
too) before the answer goes back.
ConditionType.ConditionRefresh (i=3875, and ConditionRefresh2) sends the calling
subscription a RefreshStartEvent, the latest event of every retained condition, and
RefreshEndEvent, so that a client that connects late sees the alarms in force.

This module imports neither the server nor asyncua's server API: it is a
`ServerExtension` (port.py) that app.py hands to the OPC UA sink, and it sees
the server through `ServerPort` (`add_nodes`, `delete_nodes`,
`add_event_notifier`, `trigger_event`, `link_method`, `caller_context` …).
"""

from __future__ import annotations

import asyncio
import logging
from collections import deque
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass, field
from datetime import datetime

from asyncua import ua
from asyncua.common.events import Event

from gateway.alarms.manager import AlarmManager, Check
from gateway.alarms.records import AlarmChange, AlarmRecord
from gateway.alarms.service import AlarmService
from gateway.errors import CallError, RequestError
from gateway.model.context import WriteContext
from gateway.model.sample import utcnow
from gateway.shims.ua import new_node_id
from gateway.sinks.opcua.address_space import HAS_COMPONENT
from gateway.sinks.opcua.conditions import (
    ACKNOWLEDGE,
    ALARM_CONDITION_TYPE,
    CONDITION_REFRESH,
    CONDITION_REFRESH2,
    CONFIRM,
    SERVER,
    ConditionIds,
    condition_event,
    emitted_by,
    new_event_id,
    refresh_event,
)
from gateway.sinks.opcua.port import MethodCallback, ServerPort
from gateway.sinks.opcua.values import status_code

log = logging.getLogger(__name__)

OBJECT = "Alarms"
BASE_OBJECT_TYPE = new_node_id(ua.ObjectIds.BaseObjectType)
EVENT_IDS_KEPT = 32  # recent EventIds per condition that Acknowledge/Confirm accept


def _status(name: str) -> ua.StatusCode:
    return ua.StatusCode(getattr(ua.StatusCodes, name))


@dataclass
class _Condition:
    manager: AlarmManager
    occurrence: int
    ids: ConditionIds
    severity: int
    last: Event | None = None  # the latest event, as sent (ConditionRefresh sends it again)
    event_ids: deque[bytes] = field(default_factory=lambda: deque(maxlen=EVENT_IDS_KEPT))


Action = Callable[[AlarmManager, int, WriteContext, str, Check], Awaitable[AlarmRecord]]
"""Acknowledge or Confirm on the manager: (manager, occurrence, caller, comment, EventId check)."""


class OpcUaAlarms:
    """The alarm conditions of every machine the AlarmService manages (an OPC UA ServerExtension)."""

    def __init__(self, service: AlarmService) -> None:
        self.service = service
        self._server: ServerPort | None = None
        self._conditions: dict[ua.NodeId, _Condition] = {}
        self._by_occurrence: dict[int, ua.NodeId] = {}
        self._notifiers: dict[str, ua.NodeId] = {}
        self._lock = asyncio.Lock()

    # --- set-up ------------------------------------------------------------------------------

    @property
    def server(self) -> ServerPort:
        if self._server is None:
            raise RuntimeError("the alarm conditions are not installed in an OPC UA server")
        return self._server

    async def install(self, server: ServerPort) -> None:
        """Make the machines notifiers, add the conditions still retained, and take the standard methods."""
        self._server = server
        ns = server.namespace_index
        for name, manager in self.service.managers.items():
            machine_id = server.machine_node_id(name)
            self._notifiers[name] = machine_id
            await server.add_event_notifier(machine_id)
            await server.add_nodes(
                [_object_item(new_node_id(f"{name}/{OBJECT}", ns), machine_id, OBJECT, ns)]
            )
            for record in manager.retained():
                condition = await self._condition(manager, record)
                condition.last = self._event(condition, record, record.raised_at, True)
            manager.listen(self._on_change(manager))
        server.link_method(ACKNOWLEDGE, self._method(self._acknowledge))
        server.link_method(CONFIRM, self._method(self._confirm))
        server.link_method(CONDITION_REFRESH, self._refresh)
        server.link_method(CONDITION_REFRESH2, self._refresh)

    async def _condition(self, manager: AlarmManager, record: AlarmRecord) -> _Condition:
        """The condition of an occurrence, its node added on first sight."""
        nodeid = self._by_occurrence.get(record.occurrence)
        if nodeid is not None:
            return self._conditions[nodeid]
        ns = self.server.namespace_index
        name = manager.name
        nodeid = new_node_id(f"{name}/{OBJECT}/{record.occurrence}", ns)
        parent = new_node_id(f"{name}/{OBJECT}", ns)
        await self.server.add_nodes([_condition_item(nodeid, parent, record, ns)])
        ids = ConditionIds(nodeid, self._notifiers[name], name)
        condition = _Condition(manager, record.occurrence, ids, record.severity)
        self._conditions[nodeid] = condition
        self._by_occurrence[record.occurrence] = nodeid
        return condition

    def _event(
        self,
        condition: _Condition,
        record: AlarmRecord,
        time: datetime,
        retained: bool,
        comment: str = "",
        user: str = "",
    ) -> Event:
        event_id = new_event_id()
        condition.event_ids.append(event_id)
        event = condition_event(
            record,
            condition.ids,
            event_id=event_id,
            time=time,
            retained=retained,
            last_severity=condition.severity,
            comment=comment,
            user=user,
        )
        condition.severity = record.severity
        return event

    # --- transitions -------------------------------------------------------------------------

    def _on_change(self, manager: AlarmManager) -> Callable[[AlarmChange], Awaitable[None]]:
        async def listener(change: AlarmChange) -> None:
            async with self._lock:
                condition = await self._condition(manager, change.record)
                event = self._event(
                    condition, change.record, change.ts, change.retained, change.comment, change.user
                )
                condition.last = event
                await self._send(event, condition.ids.source)
                if not change.retained:
                    await self._forget(condition)

        return listener

    async def _send(
        self, event: Event, machine_id: ua.NodeId, subscription: int | None = None, item: int | None = None
    ) -> None:
        for notifier in (SERVER, machine_id):
            await self.server.trigger_event(emitted_by(event, notifier), subscription, item)

    async def _forget(self, condition: _Condition) -> None:
        nodeid = condition.ids.condition
        self._conditions.pop(nodeid, None)
        self._by_occurrence.pop(condition.occurrence, None)
        try:
            await self.server.delete_nodes([nodeid])
        except Exception as exc:  # noqa: BLE001 - asyncua raises anything; a node left behind is only untidy
            log.warning("cannot remove the ended alarm condition %s: %s", nodeid.to_string(), exc)

    # --- Acknowledge and Confirm -------------------------------------------------------------

    def _method(self, action: Action) -> MethodCallback:
        async def callback(parent: ua.NodeId, *inputs: ua.Variant) -> ua.CallMethodResult:
            return await self._respond(parent, inputs, action)

        return callback

    async def _acknowledge(
        self, manager: AlarmManager, occurrence: int, ctx: WriteContext, comment: str, check: Check
    ) -> AlarmRecord:
        return await manager.acknowledge(occurrence, ctx, comment, check=check)

    async def _confirm(
        self, manager: AlarmManager, occurrence: int, ctx: WriteContext, comment: str, check: Check
    ) -> AlarmRecord:
        return await manager.confirm(occurrence, ctx, comment, check=check)

    async def _respond(
        self, parent: ua.NodeId, inputs: Sequence[ua.Variant], action: Action
    ) -> ua.CallMethodResult:
        """(EventId: ByteString, Comment: LocalizedText) on a condition node; never raises."""
        if len(inputs) < 2:
            return ua.CallMethodResult(StatusCode=_status("BadArgumentsMissing"))
        if len(inputs) > 2:
            return ua.CallMethodResult(StatusCode=_status("BadTooManyArguments"))
        event_id, comment = inputs
        results = [
            ua.StatusCode()
            if event_id.VariantType == ua.VariantType.ByteString and event_id.Value
            else _status("BadTypeMismatch"),
            ua.StatusCode()
            if comment.VariantType
            in (ua.VariantType.LocalizedText, ua.VariantType.String, ua.VariantType.Null)
            else _status("BadTypeMismatch"),
        ]
        if not all(r.is_good() for r in results):
            return ua.CallMethodResult(StatusCode=_status("BadTypeMismatch"), InputArgumentResults=results)
        condition = self._conditions.get(parent)
        if condition is None:
            return ua.CallMethodResult(StatusCode=_status("BadNodeIdUnknown"), InputArgumentResults=results)
        known = bytes(event_id.Value) in condition.event_ids

        def check() -> None:  # after the role check, in the manager, so that the refusal is audited
            if not known:
                raise CallError("the EventId is not one this condition reported", status="BadEventIdUnknown")

        text = comment.Value.Text if isinstance(comment.Value, ua.LocalizedText) else comment.Value
        try:
            await action(
                condition.manager, condition.occurrence, self.server.caller_context(), str(text or ""), check
            )
        except RequestError as exc:
            log.info(
                "OPC UA %s of alarm occurrence %d refused (%s): %s",
                getattr(action, "__name__", "call").strip("_"),
                condition.occurrence,
                exc.status,
                exc.reason,
            )
            return ua.CallMethodResult(StatusCode=status_code(exc.status), InputArgumentResults=results)
        except Exception:
            log.exception("OPC UA alarm call on occurrence %d failed unexpectedly", condition.occurrence)
            return ua.CallMethodResult(StatusCode=_status("BadInternalError"), InputArgumentResults=results)
        return ua.CallMethodResult(StatusCode=ua.StatusCode(), InputArgumentResults=results)

    # --- ConditionRefresh --------------------------------------------------------------------

    async def _refresh(self, parent: ua.NodeId, *inputs: ua.Variant) -> ua.CallMethodResult:
        """ConditionRefresh(SubscriptionId) and ConditionRefresh2(SubscriptionId, MonitoredItemId)."""
        if not inputs:
            return ua.CallMethodResult(StatusCode=_status("BadArgumentsMissing"))
        values = [v.Value for v in inputs]
        if any(not isinstance(v, int) or isinstance(v, bool) for v in values) or len(values) > 2:
            return ua.CallMethodResult(
                StatusCode=_status("BadTypeMismatch" if len(values) <= 2 else "BadTooManyArguments")
            )
        subscription = values[0]
        item = values[1] if len(values) == 2 else None
        if not self.server.has_subscription(subscription):
            return ua.CallMethodResult(StatusCode=_status("BadSubscriptionIdInvalid"))
        async with self._lock:
            now = utcnow()
            # The bracket goes to every event item of the subscription, past its filter (Part 9, 4.5);
            # the conditions between must pass the filter, and go through their notifiers as usual.
            await self.server.trigger_unfiltered(refresh_event(True, time=now), subscription, item)
            for condition in list(self._conditions.values()):
                if condition.last is not None:
                    await self._send(condition.last, condition.ids.source, subscription, item)
            await self.server.trigger_unfiltered(refresh_event(False, time=now), subscription, item)
        return ua.CallMethodResult(StatusCode=ua.StatusCode())


def _object_item(nodeid: ua.NodeId, parent: ua.NodeId, name: str, ns: int) -> ua.AddNodesItem:
    attrs = ua.ObjectAttributes(
        DisplayName=ua.LocalizedText(name),
        Description=ua.LocalizedText("The machine's alarms in force: one condition per occurrence"),
        WriteMask=0,
        UserWriteMask=0,
        EventNotifier=0,
    )
    return ua.AddNodesItem(
        ParentNodeId=parent,
        ReferenceTypeId=HAS_COMPONENT,
        RequestedNewNodeId=nodeid,
        BrowseName=ua.QualifiedName(name, ns),
        NodeClass=ua.NodeClass.Object,
        NodeAttributes=attrs,
        TypeDefinition=BASE_OBJECT_TYPE,
    )


def _condition_item(nodeid: ua.NodeId, parent: ua.NodeId, record: AlarmRecord, ns: int) -> ua.AddNodesItem:
    attrs = ua.ObjectAttributes(
        DisplayName=ua.LocalizedText(f"{record.id} {record.text}"),
        Description=ua.LocalizedText(f"Alarm {record.id}, occurrence {record.occurrence}"),
        WriteMask=0,
        UserWriteMask=0,
        EventNotifier=0,
    )
    return ua.AddNodesItem(
        ParentNodeId=parent,
        ReferenceTypeId=HAS_COMPONENT,
        RequestedNewNodeId=nodeid,
        BrowseName=ua.QualifiedName(f"{record.id}-{record.occurrence}", ns),
        NodeClass=ua.NodeClass.Object,
        NodeAttributes=attrs,
        TypeDefinition=ALARM_CONDITION_TYPE,
    )

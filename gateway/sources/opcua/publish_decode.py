"""Publish for the OPC UA source: the request through asyncua, the answer read by a compiled fast path.

At 5,000 changes/s about a quarter of the gateway's CPU went into asyncua's pure-Python decoding
of PublishResponses (a dataclass, a Variant, a DataValue, a StatusCode and two datetimes per
change, each built field by field). The source needs four things per change: the ClientHandle,
the Variant's value, a timestamp and the status code. `_publish.c` reads exactly those from the
bytes when the response holds only DataChangeNotifications of the usual shape, and returns None
for anything else; asyncua's `struct_from_binary` then decodes the same bytes, and `from_response`
derives the same four things from its objects. tests/unit/sources/test_publish_decode.py proves
the two agree (captured responses, Hypothesis-built ones, junk).

`PURE` (or CNC_GATEWAY_PURE_PUBLISH=1 in the environment at import) forces asyncua's decoding.
asyncua's `UaSession.publish` is the same request and the same decode; this module uses
`UaSession._send_request` and `Buffer`'s fields, which asyncua 2.x keeps stable.
"""

from __future__ import annotations

import importlib
import logging
import os
from datetime import datetime
from types import ModuleType
from typing import Any, NamedTuple

from asyncua import ua
from asyncua.common.utils import Buffer
from asyncua.ua.ua_binary import get_string_encoding, struct_from_binary
from asyncua.ua.uaerrors import UaStructParsingError

compiled: ModuleType | None
try:  # by name: grimp cannot see into a C extension and would count this import as one of the package
    compiled = importlib.import_module("gateway.sources.opcua._publish")
except ImportError:  # pragma: no cover - installed without a C compiler
    compiled = None

log = logging.getLogger(__name__)

#: Force asyncua's decoding (tests run both paths; an operator may, to rule the fast path out).
PURE = os.environ.get("CNC_GATEWAY_PURE_PUBLISH", "") not in ("", "0")

#: One data change as the source consumes it: (ClientHandle, value, SourceTimestamp or
#: ServerTimestamp or None, StatusCode value).
Change = tuple[int, Any, datetime | None, int]


class Publish(NamedTuple):
    """What the source takes from a PublishResponse."""

    service_result: int
    subscription_id: int
    sequence_number: int
    notifications: int  # len(NotificationData): acknowledged when not 0
    changes: list[Change]  # every MonitoredItemNotification of every DataChangeNotification, in order
    statuses: list[int]  # every StatusChangeNotification's status code


def decode(data: Buffer) -> Publish:
    """A PublishResponse body (from its TypeId) as the source consumes it.

    Raises asyncua's UaStructParsingError where asyncua cannot decode it, as `UaSession.publish` does.
    """
    fast = decode_fast(data)
    if fast is not None:
        return fast
    size = len(data)
    try:
        response = struct_from_binary(ua.PublishResponse, data)
    except Exception as exc:
        log.warning("undecodable PublishResponse (%d bytes): %s: %s", size, type(exc).__name__, exc)
        raise UaStructParsingError from exc
    return from_response(response)


def decode_fast(data: Buffer) -> Publish | None:
    """The compiled reader's answer, or None where it is not built, forced off or not certain."""
    if compiled is None or PURE:
        return None
    raw = data._data  # Buffer keeps its bytes, start and length in these
    if type(raw) is not bytes or get_string_encoding() != "utf-8":
        return None  # asyncua reads memoryviews and other string encodings its own way
    found = compiled.decode(raw, data._cur_pos, data._size)
    if found is None:
        return None
    result, subscription, sequence, notifications, changes = found
    return Publish(result, subscription, sequence, notifications, changes, [])


def from_response(response: ua.PublishResponse) -> Publish:
    """asyncua's decoded PublishResponse, reduced to what the source consumes: the reference."""
    result = response.Parameters
    message = result.NotificationMessage
    changes, statuses = from_notifications(message.NotificationData)
    return Publish(
        response.ResponseHeader.ServiceResult.value,
        result.SubscriptionId,
        message.SequenceNumber,
        len(message.NotificationData or ()),
        changes,
        statuses,
    )


def from_notifications(data: list[Any] | None) -> tuple[list[Change], list[int]]:
    """Data changes and status changes from NotificationData; other notifications (events) are not ours."""
    changes: list[Change] = []
    statuses: list[int] = []
    for notification in data or ():
        if type(notification) is ua.DataChangeNotification:
            for item in notification.MonitoredItems:
                dv = item.Value
                variant = dv.Value
                code = dv.StatusCode
                changes.append(
                    (
                        item.ClientHandle,
                        None if variant is None else variant.Value,
                        dv.SourceTimestamp or dv.ServerTimestamp,
                        0 if code is None else code.value,
                    )
                )
        elif isinstance(notification, ua.StatusChangeNotification):
            statuses.append(notification.Status.value)
    return changes, statuses


async def publish(session: Any, acks: list[ua.SubscriptionAcknowledgement]) -> Publish:
    """`UaSession.publish`, answered as a Publish. Raises what it raises."""
    request = ua.PublishRequest()
    request.Parameters.SubscriptionAcknowledgements = acks
    data = await session._send_request(request, timeout=0)  # UaSession.publish's own call
    return decode(data)

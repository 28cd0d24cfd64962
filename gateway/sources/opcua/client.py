"""The OPC UA client driver: keeps one machine's variables in step with its controller.

Covers controllers with an OPC UA server (B&R, Siemens, Beckhoff, Fanuc with the
option) and the simulator. Design choices, and why:

* **Own reconnect loop.** asyncua runs with `auto_reconnect=False`; its supervisor
  only reports a loss (`connection_lost_callback`), and this driver tears the
  client down and starts over with backoff. A fresh session after every loss is
  what controllers handle best, and it re-resolves `nsu=` namespaces each time.
* **Own publish loop.** asyncua's loop hands every notification to a new task (or
  a queue) and logs stack traces when the socket drops. Here one task sends the
  Publish requests and feeds each data change straight into `Machine.ingest`,
  synchronously, through a ClientHandle → node dict. The answers are read by
  gateway.sources.opcua.publish_decode: a compiled reader for the usual data changes,
  asyncua's own decoding for everything else.
* **Errors stop here.** asyncua's exceptions are translated into gateway.errors
  (writes) or into a Bad status plus one readable log line (connection), never
  a traceback for something as ordinary as a controller being switched off.
* **Writes read back.** After a Good write the variable is read from the controller
  in the same session and the reading handed to the tree before the write is
  answered, so a client that reads right after writing sees its value
  (docs/architecture.md, Writes).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from collections import deque
from collections.abc import Callable, Coroutine, Sequence
from datetime import datetime
from typing import Any, Self

from asyncua import Client, ua
from asyncua.client.ua_client import UaClientState
from asyncua.crypto import uacrypto
from asyncua.ua.uaerrors import (
    BadTimeout,
    BadTooManyPublishRequests,
    UaStatusCodeError,
    UaStructParsingError,
)
from cryptography import x509

from gateway.codecs.opcua_nodeid import OpcUaAddress, parse_address
from gateway.errors import AddressError, ControllerRefused, ControllerUnavailable
from gateway.model.sample import ReadBack, utcnow
from gateway.model.tree import Machine, VariableNode
from gateway.model.types import INT_BOUNDS, DataType, TypeSpec
from gateway.reconnect import Backoff, OutageLog
from gateway.shims.ua import new_node_id, new_status_error
from gateway.sources.base import DriverMapping, settings_of
from gateway.sources.opcua.asyncua_logs import quiet_asyncua_logging
from gateway.sources.opcua.config import OpcUaDriver
from gateway.sources.opcua.publish_decode import Change, Publish, from_notifications, publish
from gateway.sources.opcua.status import describe_error, status_doc, status_name

log = logging.getLogger(__name__)

# Unless the application set the asyncua loggers up itself, keep them to errors.
quiet_asyncua_logging(logging.ERROR if logging.getLogger("asyncua").level == logging.NOTSET else None)

BATCH_SIZE = 500  # monitored items per CreateMonitoredItems request
SESSION_TIMEOUT_MS = 60_000  # the server drops our session a minute after we vanish
CLOSE_BUDGET = 0.5  # seconds allowed for a polite CloseSession on the way out
KEEPALIVE_MS = 5_000  # the server sends an empty publish response at least this often

_NODE_ID_TYPES = {
    "i": ua.NodeIdType.Numeric,
    "s": ua.NodeIdType.String,
    "g": ua.NodeIdType.Guid,
    "b": ua.NodeIdType.ByteString,
}

_PY_TYPES: dict[DataType, type] = {
    DataType.BOOLEAN: bool,
    DataType.FLOAT: float,
    DataType.DOUBLE: float,
    DataType.STRING: str,
    DataType.DATETIME: datetime,
    **dict.fromkeys(INT_BOUNDS, int),
}

Lost = Callable[[str, str], None]


# --- client set-up and tear-down (shared with discover) ----------------------------------------


async def open_client(
    endpoint: str,
    *,
    timeout: float,
    username: str | None = None,
    password: str | None = None,
    security: str = "None",
    watchdog_interval: float = 1.0,
    on_lost: Callable[[Exception], Coroutine[Any, Any, None]] | None = None,
) -> Client:
    """Connect and activate a session. Raises what asyncua raises; closes the client on failure."""
    client = Client(endpoint, timeout=timeout, watchdog_intervall=watchdog_interval, auto_reconnect=False)
    client.name = client.description = "cnc-gateway"
    client.application_uri = "urn:cnc-gateway:client"
    client.product_uri = "urn:cnc-gateway"
    client.session_timeout = SESSION_TIMEOUT_MS
    client.connection_lost_callback = on_lost
    if username:
        client.set_user(username)
    if password:
        client.set_password(password)
    try:
        if security and security.strip() != "None":
            uri = await certificate_uri(security)
            if uri:  # the session must announce the URI its certificate carries, or servers refuse it
                client.application_uri = uri
            await client.set_security_string(security.strip())
        await client.connect()
    except BaseException:
        await close_client(client, polite=False)
        raise
    return client


async def close_client(client: Client, *, polite: bool) -> None:
    """Tear a client down quickly, without raising and without asyncua logging a traceback.

    `polite` sends CloseSession (which also deletes our subscription on the
    server) when the connection is up, within CLOSE_BUDGET; otherwise, or if that
    fails, the socket is simply aborted and the client's tasks stopped.
    """
    # asyncua's own task cancelling swallows a CancelledError aimed at *our* task while it
    # waits; notice that by the task's cancel count and raise it again afterwards.
    current = asyncio.current_task()
    cancels = current.cancelling() if current is not None else 0
    await _teardown(client, polite)
    if current is not None and current.cancelling() > cancels:
        raise asyncio.CancelledError


async def _teardown(client: Client, polite: bool) -> None:
    uaclient = client.uaclient
    # Best effort throughout: a session that is going away fails in any of asyncua's ways (and a polite close
    # that fails falls back to the abort below), so nothing here is worth raising or logging.
    if polite and uaclient.state is UaClientState.CONNECTED:
        try:
            async with asyncio.timeout(CLOSE_BUDGET):
                await client.disconnect()
            return
        except Exception:  # noqa: BLE001, S110 - see above
            pass
    proto = uaclient.protocol
    if proto is not None and proto.transport is not None:
        proto.transport.abort()
        await asyncio.sleep(0)  # let connection_lost run, so closing sends nothing on a dead socket
    with contextlib.suppress(Exception):
        async with asyncio.timeout(CLOSE_BUDGET):
            await client.close_session()
    with contextlib.suppress(Exception):
        uaclient.disconnect_socket()


async def certificate_uri(security: str) -> str | None:
    """The application URI in the client certificate a security string names (Policy,Mode,cert,key)."""
    parts = [p.strip() for p in security.split(",")]
    if len(parts) < 3 or not parts[2]:
        return None
    try:
        cert = await uacrypto.load_certificate(parts[2])
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName)
    except Exception:  # noqa: BLE001 - set_security_string reports an unreadable certificate itself
        return None
    uris = san.value.get_values_for_type(x509.UniformResourceIdentifier)
    return uris[0] if uris else None


def _no_publish_loop() -> None:
    """Replaces asyncua's publish loop starter: OpcUaSource runs its own."""


# --- the driver --------------------------------------------------------------------------------


class OpcUaSource:
    """One machine's OPC UA connection: subscribe, ingest, reconnect, write."""

    def __init__(self, machine: Machine, mapping: DriverMapping) -> None:
        self.machine = machine
        self.mapping = mapping
        self.driver = settings_of(mapping, OpcUaDriver)  # the registry picks this class by the driver's type
        self._client: Client | None = None
        self._connected = False
        self._publish_task: asyncio.Task[None] | None = None
        self._last_reason = "not connected yet"
        self._outage = OutageLog(log)  # says the controller's absence once, and its return
        # Parsed once; resolved to NodeIds at every connect (namespace indexes may change).
        self._addresses: dict[VariableNode, OpcUaAddress] = {}
        self._address_errors: dict[VariableNode, str] = {}
        self._node_ids: dict[VariableNode, ua.NodeId] = {}
        self._handles: dict[int, tuple[VariableNode, type]] = {}
        self._failed: set[VariableNode] = set()  # variables whose value made ingest fail (logged once)
        # How long after a write's read-back an older notification may still be on its way (ReadBack.hold):
        # sampled before the write, queued until the next publish, then sent.
        slowest = max((mapping.sampling_interval(v) for v in mapping.variables), default=0.0)
        self._hold = 2.0 * (self.driver.publishing_interval + slowest) / 1000.0 + 1.0
        for handle, node in enumerate(machine.mapped, start=1):
            try:
                self._addresses[node] = parse_address(node.definition.source)
            except AddressError as exc:
                self._address_errors[node] = str(exc)
                continue
            raw = node.definition.raw_type
            self._handles[handle] = (node, list if raw.array else _PY_TYPES[raw.base])

    def __repr__(self) -> str:
        return f"<OpcUaSource {self.machine.name} {self.driver.endpoint}>"

    # --- lifecycle -------------------------------------------------------------------------

    async def __aenter__(self) -> Self:
        self.machine.writer = self
        self._mark_bad_addresses()
        for node, reason in self._address_errors.items():
            log.warning("%s: %s is not subscribed: %s", self.machine.name, node.path, reason)
        if self._address_errors:
            self.machine.status.error(
                f"{len(self._address_errors)} variable(s) have an invalid address: "
                + _first(n.path for n in self._address_errors)
            )
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self._stop()
        if self.machine.writer is self:
            self.machine.writer = None

    async def _stop(self) -> None:
        """Close politely; the status says so, the values keep their last status until a restart."""
        was_connected = self._connected
        await self._close(polite=True)
        if was_connected:
            self.machine.status.disconnected("gateway stopped")

    async def run(self) -> None:
        """Connect, subscribe, reconnect with backoff until cancelled. Never raises for controller trouble."""
        backoff = Backoff.of(self.driver.reconnect)
        try:
            while True:
                self.machine.status.connecting()
                try:
                    loss = await self._connect()
                except Exception as exc:  # noqa: BLE001 - asyncua's failures, translated by describe_error
                    status, reason, expected = describe_error(exc)
                    await self._drop(status, reason, None if expected else exc)
                else:
                    backoff.reset()
                    status, reason = await loss
                    await self._drop(status, reason, None)
                await asyncio.sleep(backoff.next())
        finally:
            await self._stop()

    # --- connecting ------------------------------------------------------------------------

    async def _connect(self) -> asyncio.Future[tuple[str, str]]:
        """Open a session and subscribe everything; returns a future that resolves on loss."""
        loss: asyncio.Future[tuple[str, str]] = asyncio.get_running_loop().create_future()

        def lost(status: str, reason: str) -> None:
            if not loss.done():
                loss.set_result((status, reason))

        async def on_connection_lost(exc: Exception) -> None:
            status, reason, _ = describe_error(exc)
            if isinstance(exc, TimeoutError):
                reason = "controller stopped answering (watchdog timeout)"
            lost(status, reason)

        d = self.driver
        client = await open_client(
            d.endpoint,
            timeout=d.timeout,
            username=d.username,
            password=d.password.get_secret_value() if d.password is not None else None,
            security=d.security,
            watchdog_interval=d.watchdog_interval,
            on_lost=on_connection_lost,
        )
        self._client = client
        namespaces = await client.get_namespace_array()
        unresolved = self._resolve(namespaces)
        session = client.uaclient.session
        session.ensure_publish_loop = _no_publish_loop  # type: ignore[method-assign]
        requested = self._subscription_parameters()
        result = await session.create_subscription(requested, callback=self._on_informed(lost))
        refused = await self._create_items(session, result.SubscriptionId)
        interval = result.RevisedPublishingInterval or requested.RequestedPublishingInterval
        keepalive_s = (
            interval * (result.RevisedMaxKeepAliveCount or requested.RequestedMaxKeepAliveCount) / 1000.0
        )
        self._publish_task = asyncio.create_task(
            self._publish_loop(session, lost, stall_after=2 * keepalive_s + d.timeout),
            name=f"opcua-publish:{self.machine.name}",
        )
        self._connected = True
        self.machine.status.connected()
        problems = unresolved + refused
        self._outage.recovered(
            "%s: connected to %s, %d variables subscribed%s",
            self.machine.name,
            d.endpoint,
            len(self._node_ids) - len(refused),
            f", {len(problems)} not available" if problems else "",
        )
        if problems:
            message = f"{len(problems)} variable(s) not available: {_first(problems)}"
            log.warning("%s: %s", self.machine.name, message)
            self.machine.status.error(message)
        return loss

    def _resolve(self, namespaces: Sequence[str]) -> list[str]:
        """NodeIds for this server's namespace array; variables whose namespace is missing turn Bad."""
        self._node_ids.clear()
        problems = []
        now = utcnow()
        for node, address in self._addresses.items():
            try:
                index = address.resolve(list(namespaces))
            except AddressError as exc:
                self.machine.ingest(node, None, now, "BadNodeIdUnknown", f"{node.definition.source}: {exc}")
                problems.append(f"{node.path} (BadNodeIdUnknown)")
                continue
            self._node_ids[node] = new_node_id(address.identifier, index, _NODE_ID_TYPES[address.kind])
        return problems

    def _subscription_parameters(self) -> ua.CreateSubscriptionParameters:
        interval = self.driver.publishing_interval
        keepalive = max(1, math.ceil(KEEPALIVE_MS / interval))
        return ua.CreateSubscriptionParameters(
            RequestedPublishingInterval=interval,
            RequestedLifetimeCount=keepalive * 6,
            RequestedMaxKeepAliveCount=keepalive,
            MaxNotificationsPerPublish=0,
            PublishingEnabled=True,
            Priority=0,
        )

    async def _create_items(self, session: Any, subscription_id: int) -> list[str]:
        """Monitored items in batches; an item the server refuses turns only its variable Bad."""
        mapping = self.mapping
        specs = {v.path: v for v in mapping.variables}
        wanted = [(h, node) for h, (node, _) in self._handles.items() if node in self._node_ids]
        refused: list[str] = []
        for start in range(0, len(wanted), BATCH_SIZE):
            batch = wanted[start : start + BATCH_SIZE]
            requests = [
                ua.MonitoredItemCreateRequest(
                    ItemToMonitor=ua.ReadValueId(
                        NodeId=self._node_ids[node], AttributeId=ua.AttributeIds.Value
                    ),
                    MonitoringMode=ua.MonitoringMode.Reporting,
                    RequestedParameters=ua.MonitoringParameters(
                        ClientHandle=handle,
                        SamplingInterval=mapping.sampling_interval(specs[node.path]),
                        QueueSize=mapping.queue_size(specs[node.path]),
                        DiscardOldest=True,
                    ),
                )
                for handle, node in batch
            ]
            params = ua.CreateMonitoredItemsParameters(
                SubscriptionId=subscription_id,
                TimestampsToReturn=ua.TimestampsToReturn.Both,
                ItemsToCreate=requests,
            )
            results = await session.create_monitored_items(params)
            now = utcnow()
            for (_, node), res in zip(batch, results, strict=True):
                code = res.StatusCode.value
                if code & 0x80000000:
                    name = status_name(code)
                    self.machine.ingest(
                        node, None, now, name, f"{node.definition.source}: {name} ({status_doc(code)})"
                    )
                    refused.append(f"{node.path} ({name})")
        return refused

    # --- losing the connection -------------------------------------------------------------

    async def _drop(self, status: str, reason: str, unexpected: BaseException | None) -> None:
        """Tear down after a failed attempt or a loss: variables Bad, status, one log line per transition."""
        was_connected = self._connected
        await self._close(polite=False)
        self.machine.invalidate(status, reason)
        self._mark_bad_addresses()
        self.machine.status.disconnected(reason)
        name, endpoint, outage = self.machine.name, self.driver.endpoint, self._outage
        if unexpected is not None:
            outage.failed(reason, "%s: %s; retrying", name, reason, level=logging.ERROR, exc_info=unexpected)
        elif was_connected:
            outage.failed(reason, "%s: lost connection to %s: %s; reconnecting", name, endpoint, reason)
        elif not outage.down:
            outage.failed(reason, "%s: cannot connect to %s: %s; will keep retrying", name, endpoint, reason)
        else:
            outage.failed(
                reason, "%s: still cannot connect to %s: %s", name, endpoint, reason, level=logging.INFO
            )
        self._last_reason = reason

    async def _close(self, *, polite: bool) -> None:
        self._connected = False
        task, self._publish_task = self._publish_task, None
        if task is not None:
            task.cancel()
            await asyncio.wait([task])
        client, self._client = self._client, None
        if client is not None:
            await close_client(client, polite=polite)

    def _mark_bad_addresses(self) -> None:
        now = utcnow()
        for node, reason in self._address_errors.items():
            self.machine.ingest(node, None, now, "BadNodeIdInvalid", reason)

    # --- receiving -------------------------------------------------------------------------

    async def _publish_loop(self, session: Any, lost: Lost, *, stall_after: float) -> None:
        """One Publish request in flight at a time; each answer goes straight into the tree.

        Every way out of this loop except cancellation reports a loss, so a dead
        subscription never leaves the machine looking connected.
        """
        try:
            await self._receive(session, lost, stall_after)
        except Exception as exc:  # a bug, not a controller problem: say so with the traceback, then reconnect
            log.error("%s: receiving failed", self.machine.name, exc_info=exc)
            lost("BadInternalError", f"unexpected error: {type(exc).__name__}: {exc}")

    async def _receive(self, session: Any, lost: Lost, stall_after: float) -> None:
        """`publish_requests` requests at the controller (1 by default: the next once an answer is in).
        Answers are taken in the order they come (the session's one connection keeps it); each answer's
        acknowledgement goes with the next request."""
        acks: list[ua.SubscriptionAcknowledgement] = []
        wanted = self.driver.publish_requests
        pending: deque[asyncio.Task[Publish]] = deque()
        try:
            while True:
                while len(pending) < wanted:
                    pending.append(asyncio.create_task(publish(session, acks), name="opcua:publish"))
                    acks = []
                task = pending[0]
                try:
                    async with asyncio.timeout(stall_after):
                        response = await asyncio.shield(task)
                except (BadTimeout, BadTooManyPublishRequests):
                    await asyncio.sleep(0.05)
                    continue
                except UaStructParsingError:
                    continue  # one undecodable message (logged); the next one may be fine
                except TimeoutError:
                    lost("BadCommunicationError", "subscription stalled (no publish response)")
                    return
                except Exception as exc:  # noqa: BLE001 - whatever asyncua raised ends this session only
                    status, reason, _ = describe_error(exc)
                    lost(status, reason)
                    return
                finally:
                    if task.done():
                        pending.popleft()
                if response.service_result & 0x80000000:
                    lost(*describe_error(new_status_error(response.service_result))[:2])
                    return
                if response.notifications:
                    acks.append(
                        ua.SubscriptionAcknowledgement(
                            SubscriptionId=response.subscription_id, SequenceNumber=response.sequence_number
                        )
                    )
                    self._process(response.changes, response.statuses, lost)
        finally:
            for task in pending:
                task.cancel()
            if pending:
                await asyncio.wait(pending, timeout=1.0)

    def _on_informed(self, lost: Lost) -> Callable[[ua.PublishResult], None]:
        """The callback asyncua calls when its supervisor tells subscriptions the connection is gone."""

        def callback(result: ua.PublishResult) -> None:
            self._process(*from_notifications(result.NotificationMessage.NotificationData), lost)

        return callback

    def _process(self, changes: list[Change], statuses: list[int], lost: Lost) -> None:
        """Hot path: every data change goes straight to `Machine.ingest`."""
        handles = self._handles
        ingest = self.machine.ingest
        for handle, value, stamp, code in changes:
            entry = handles.get(handle)
            if entry is None:
                continue
            node, expected = entry
            ts = utcnow() if stamp is None or stamp.year < 1971 else stamp
            try:
                if code == 0 and type(value) is expected:
                    ingest(node, value, ts)
                else:
                    self._ingest_other(node, value, ts, code)
            except Exception as exc:  # noqa: BLE001 - one odd value must not stop the others
                self._ingest_failed(node, value, exc)
        for code in statuses:
            if code & 0x80000000:
                status, reason, _ = describe_error(new_status_error(code))
                lost(status, reason)

    def _ingest_failed(self, node: VariableNode, value: Any, exc: Exception) -> None:
        reason = f"cannot take {value!r:.40}: {type(exc).__name__}: {exc}"
        if node not in self._failed:
            self._failed.add(node)
            log.error("%s: %s: %s", self.machine.name, node.path, reason, exc_info=exc)
        self.machine.ingest(node, None, utcnow(), "BadInternalError", reason)

    def _ingest_other(self, node: VariableNode, value: Any, ts: datetime, code: int) -> None:
        """The slow path: a non-Good status, or a value whose Python type is not the mapped one."""
        name = status_name(code)
        if code & 0x80000000:
            self.machine.ingest(node, None, ts, name, f"controller reports {name} ({status_doc(code)})")
            return
        converted, problem = _convert(node.definition.raw_type, value)
        if problem:
            self.machine.ingest(
                node, None, ts, "BadTypeMismatch", f"{problem}, mapping says {node.definition.raw_type}"
            )
        else:
            self.machine.ingest(node, converted, ts, name)

    # --- writing ---------------------------------------------------------------------------

    async def write(self, node: VariableNode, raw: Any) -> ReadBack | None:
        """Write one raw value as a Variant of the mapped type, value only (no timestamps, no status);
        answer with the value read back from the controller (None if it could not be read)."""
        client = self._client
        if client is None or not self._connected:
            raise ControllerUnavailable(
                f"{self.machine.name} is not connected to its controller ({self._last_reason})"
            )
        node_id = self._node_ids.get(node)
        if node_id is None:
            bad = node.sample.status if node.sample.status.startswith("Bad") else "BadNodeIdUnknown"
            raise ControllerRefused(
                f"{node.definition.source} is not available: {node.sample.reason}", status=bad
            )
        raw_type = node.definition.raw_type
        try:
            variant = ua.Variant(
                list(raw) if raw_type.array else raw,
                ua.VariantType[raw_type.base.value],
                is_array=raw_type.array,
            )
        except Exception as exc:  # noqa: BLE001 - asyncua's encoders raise anything
            raise ControllerRefused(
                f"cannot encode {raw!r} as {raw_type}: {exc}", status="BadTypeMismatch"
            ) from None
        params = ua.WriteParameters(
            NodesToWrite=[
                ua.WriteValue(
                    NodeId=node_id,
                    AttributeId=ua.AttributeIds.Value,
                    Value=ua.DataValue(variant, StatusCode=None),
                )
            ]
        )
        timeout = self.driver.timeout
        try:
            async with asyncio.timeout(timeout):
                results = await client.uaclient.session.write(params)
        except TimeoutError:
            raise ControllerUnavailable(
                f"the controller did not answer the write within {timeout:g} s", status="BadTimeout"
            ) from None
        except UaStatusCodeError as exc:
            name = status_name(exc.code)
            raise ControllerRefused(
                f"controller refused: {name} ({status_doc(exc.code)})", status=name
            ) from None
        except (ConnectionError, OSError):
            raise ControllerUnavailable(
                "the connection to the controller was lost during the write"
            ) from None
        except Exception as exc:  # noqa: BLE001 - the rest of asyncua's failures
            raise ControllerUnavailable(f"write failed: {type(exc).__name__}: {exc}") from None
        code = results[0].value if results else 0x80010000
        if code & 0x80000000:
            name = status_name(code)
            raise ControllerRefused(f"controller refused: {name} ({status_doc(code)})", status=name)
        return await self._read_back(client, node, node_id)

    async def _read_back(self, client: Client, node: VariableNode, node_id: ua.NodeId) -> ReadBack | None:
        """The written variable as the controller holds it now, for the tree (read-your-writes).

        The write has succeeded whatever happens here: a read that fails or times out
        only means the value arrives the usual way, by the subscription.
        """
        params = ua.ReadParameters(
            MaxAge=0,
            TimestampsToReturn=ua.TimestampsToReturn.Both,
            NodesToRead=[ua.ReadValueId(NodeId=node_id, AttributeId=ua.AttributeIds.Value)],
        )
        try:
            async with asyncio.timeout(self.driver.timeout):
                results = await client.uaclient.session.read(params)
        except Exception as exc:  # noqa: BLE001 - a timeout, a refusal, a lost link: the write stands
            log.debug("%s: reading %s back after the write failed: %s", self.machine.name, node.path, exc)
            return None
        if not results:
            return None
        dv = results[0]
        code = 0 if dv.StatusCode is None else dv.StatusCode.value
        if code & 0x80000000:
            return None
        variant = dv.Value
        value, problem = _convert(node.definition.raw_type, None if variant is None else variant.Value)
        if problem:
            return None
        stamp = dv.SourceTimestamp or dv.ServerTimestamp
        ts = stamp if stamp is not None and stamp.year >= 1971 else utcnow()
        return ReadBack(value, ts, status_name(code), hold=self._hold)


def _convert(spec: TypeSpec, value: Any) -> tuple[Any, str]:
    """Reconcile a controller value with the mapped type: (value, "") or (None, what is wrong)."""
    if value is None:
        if spec.array:
            return [], ""
        if spec.base is DataType.STRING:
            return "", ""
        return None, "controller sent no value"
    if spec.array:
        if isinstance(value, (list, tuple)):
            return list(value), ""
        return None, f"controller sent a scalar {type(value).__name__}"
    base = spec.base
    if base in (DataType.FLOAT, DataType.DOUBLE) and type(value) is int:
        return float(value), ""
    if base is DataType.STRING and isinstance(value, ua.LocalizedText):
        return value.Text or "", ""
    expected = _PY_TYPES[base]
    if type(value) is expected or (
        expected is not bool and expected is not int and isinstance(value, expected)
    ):
        return value, ""
    if isinstance(value, list):
        return None, "controller sent an array"
    return None, f"controller sent {type(value).__name__} {value!r:.40}"


def _first(items: Sequence[str] | Any, limit: int = 5) -> str:
    items = list(items)
    text = ", ".join(str(i) for i in items[:limit])
    return text + (f" and {len(items) - limit} more" if len(items) > limit else "")

"""The OPC UA server sink: the address space SCADA clients browse, subscribe to and write through.

This is the one module that touches asyncua's server API. It starts the server,
adds the tree's nodes in batches through the internal session, mirrors every
change from the hub into the address space, and routes client writes of our
variables through the tree by replacing the server's attribute service.

Seams for the work that builds on this server: parts such as the alarm
conditions are `ServerExtension`s given to the constructor, installed once the
tree's nodes exist, and see the server through `port.ServerPort` (add and delete
nodes, event notifiers, events, method callbacks, the caller); this module
imports none of them. `user_name`/`user_role` turn a session's user into the
name and role passed to the tree in `WriteContext`.

Users and security: logins go to `identity.GatewayUserManager` (the gateway's
users, anonymous role, lockout per address); each session's UserAccessLevel and
UserExecutable are answered for its role; endpoints, the server certificate and
the client trust list come from `security.py`.
"""

from __future__ import annotations

import asyncio
import gc
import logging
import socket
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from datetime import datetime
from pathlib import Path
from typing import Any, Self
from urllib.parse import urlsplit

from asyncua import Server, ua
from asyncua.common.events import Event
from asyncua.crypto.permission_rules import User, UserRole
from asyncua.server.address_space import AddressSpace, AttributeService

from gateway import __version__
from gateway.auth.users import UserDirectory
from gateway.errors import SinkError
from gateway.model.context import WriteContext
from gateway.model.hub import Change, Subscription
from gateway.model.methods import Method
from gateway.model.sample import Sample, utcnow
from gateway.model.tree import Machine, VariableNode, VariableTree
from gateway.shards.identity import shard_index
from gateway.shims.asyncua_nodesets import import_nodesets
from gateway.shims.asyncua_ns0 import default_cache_dir, loaded_node_ids, use_cache
from gateway.shims.asyncua_server import (
    forget_standard_namespace_code,
    keep_written_values,
    slim_attribute_values,
)
from gateway.shims.ua import new_node_id, new_status_code
from gateway.sinks.base import SinkHealth
from gateway.sinks.opcua.address_space import AddressSpacePlan
from gateway.sinks.opcua.asyncua_tuning import SharedAttributes
from gateway.sinks.opcua.bulk import NodeWriter
from gateway.sinks.opcua.config import OpcUaServerConfig
from gateway.sinks.opcua.identity import (
    CLIENT_ADDRESS,
    GatewayUserManager,
    address_of,
    report_anonymous,
    session_role,
    user_access_level,
    user_executable,
)
from gateway.sinks.opcua.methods import call_result, plan_methods
from gateway.sinks.opcua.port import MethodCallback, ServerExtension, Shown
from gateway.sinks.opcua.redundancy import RedundantSet, application_uri, keep_level
from gateway.sinks.opcua.redundancy import install as install_redundancy
from gateway.sinks.opcua.security import ClientCertificates, Pki, secure_server
from gateway.sinks.opcua.values import ValueKind, ValueMismatch, value_kind
from gateway.sinks.opcua.writes import write_node

log = logging.getLogger(__name__)

# The caller AttributeService.write assumes when it is given none (asyncua's own default: every right).
_ADMIN = User(role=UserRole.Admin)

ADD_BATCH = 2000  # AddNodesItems per call; the loop gets a turn between batches
YIELD_EVERY = 1000  # value writes between turns for the rest of the loop
# Notifications kept per monitored item for a client that does not collect them; a client's "0: as many as
# you allow" is revised to this. asyncua's own cap, 10,000, lets one stalled client (no Publish requests)
# hold about 270 bytes x 10,000 x every variable it watches (tests/integration/drills/test_slow_consumers.py).
MAX_QUEUE_PER_ITEM = 100
SERVER_OBJECT = new_node_id(ua.ObjectIds.Server)
HAS_NOTIFIER = new_node_id(ua.ObjectIds.HasNotifier)

# The session user of the Call request being served: asyncua does not pass it to method callbacks.
_CALLER: ContextVar[Any] = ContextVar("opcua_caller", default=None)
# The session whose Read request is being served (UserAccessLevel per session); unset for internal reads.
_READER: ContextVar[Any] = ContextVar("opcua_reader", default=None)


def _track_callers(iserver: Any, bserver: Callable[[], Any]) -> None:
    """Hook every new session: its Call and Read services record its user (_CALLER, _READER) while
    they run; ActivateSession learns the client's address (identity.CLIENT_ADDRESS); and on a
    channel without security the client certificate is ignored (OPC UA Part 4, 5.6.2), so that an
    untrusted client on the None endpoint is not refused for a certificate nobody checks there."""
    create_session = iserver.create_session

    def create(*args: Any, **kwargs: Any) -> Any:
        session = create_session(*args, **kwargs)
        call, read = session.call, session.read
        activate, create_ = session.activate_session, session.create_session

        async def call_as_user(params: list[ua.CallMethodRequest]) -> list[ua.CallMethodResult]:
            token = _CALLER.set(session.user)
            try:
                results: list[ua.CallMethodResult] = await call(params)
                return results
            finally:
                _CALLER.reset(token)

        async def read_as_user(params: ua.ReadParameters) -> list[ua.DataValue]:
            token = _READER.set(session)
            try:
                values: list[ua.DataValue] = await read(params)
                return values
            finally:
                _READER.reset(token)

        def activate_from(*a: Any, **kw: Any) -> Any:
            token = CLIENT_ADDRESS.set(address_of(session.name))
            try:
                return activate(*a, **kw)
            finally:
                CLIENT_ADDRESS.reset(token)

        async def create_on_channel(params: ua.CreateSessionParameters, *a: Any, **kw: Any) -> Any:
            if params.ClientCertificate and _channel_unsecured(bserver(), session):
                params.ClientCertificate = None
            return await create_(params, *a, **kw)

        session.call = call_as_user
        session.read = read_as_user
        session.activate_session = activate_from
        session.create_session = create_on_channel
        return session

    iserver.create_session = create


_REFUSALS_WE_LOG = (
    "BadUserAccessDenied",
    "BadIdentityTokenRejected",
    "BadCertificateUntrusted",
    "BadCertificateTimeInvalid",
    "BadCertificateUriInvalid",
    "BadCertificateInvalid",
    "BadCertificateUseNotAllowed",
)


class _QuietRefusals(logging.Filter):
    """asyncua logs every refused login or certificate as an ERROR; the gateway already logs each one
    in a line that says who and why (gateway.auth, security.py). Drop asyncua's duplicate, and say
    plainly what its "token not supported" means."""

    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        fault = message.startswith("sending service fault response")
        if fault and any(name in message for name in _REFUSALS_WE_LOG):
            return False
        if message.startswith("Rejected active session UserIdentityToken not supported"):
            record.msg = (
                "OPC UA: login refused: the client used an identity token this server does not offer "
                "(anonymous logins are refused: access.anonymous)"
            )
            record.args = None
            record.levelno, record.levelname = logging.WARNING, "WARNING"
        return True


_QUIET = _QuietRefusals()
for _name in ("asyncua.server.uaprocessor", "asyncua.server.internal_session"):
    if _QUIET not in logging.getLogger(_name).filters:
        logging.getLogger(_name).addFilter(_QUIET)


def _channel_unsecured(bserver: Any, session: Any) -> bool:
    """Whether `session` was created on a SecureChannel with MessageSecurityMode None.

    asyncua does not tell the session; its connection does (a private attribute,
    read defensively: when in doubt, the certificate is checked)."""
    for protocol in getattr(bserver, "clients", ()):
        processor = getattr(protocol, "processor", None)
        if processor is not None and processor.session is session:
            policy = getattr(getattr(processor, "_connection", None), "security_policy", None)
            return getattr(policy, "Mode", None) == ua.MessageSecurityMode.None_
    return False


def session_user_role(user: Any) -> str | None:
    """Default `OpcUaSink.user_role`: the gateway role of the session (identity.SessionUser)."""
    return session_role(user)


def session_user_name(user: Any) -> str | None:
    """Default `OpcUaSink.user_name`: the name asyncua's user manager gave the session, if any."""
    name = getattr(user, "name", None)
    return name if isinstance(name, str) and name else None


class _Variable:
    """What the sink caches per tree variable: its node, id and type, the record asyncua keeps its Value in
    (`held`), and, while no client monitors it, the sample last pushed and when (read through `held`)."""

    __slots__ = ("held", "kind", "node", "nodeid", "pushed_at", "sample")

    def __init__(self, node: VariableNode, nodeid: ua.NodeId, kind: ValueKind, held: Any) -> None:
        self.node = node
        self.nodeid = nodeid
        self.kind = kind
        self.held = held
        self.sample: Sample | None = None
        self.pushed_at: datetime | None = None


class _GatewayAttributeService(AttributeService):
    """asyncua's attribute service, except that writes to our nodes go to the tree.

    Writes from the server's own internal session (asyncua itself, other gateway
    components writing locally) keep asyncua's behaviour.
    """

    def __init__(self, aspace: AddressSpace, sink: OpcUaSink, internal_user: User) -> None:
        super().__init__(aspace)
        self._sink = sink
        self._internal_user = internal_user

    def read(self, params: ua.ReadParameters) -> list[ua.DataValue]:
        """asyncua's read, except UserAccessLevel and UserExecutable of our nodes, which depend on the
        reading session's role (asyncua's Read service does not pass the user: see _READER)."""
        results = super().read(params)
        reader = _READER.get()
        if reader is None:  # the server itself
            return results
        per_user = (ua.AttributeIds.UserAccessLevel, ua.AttributeIds.UserExecutable)
        items = params.NodesToRead
        if not any(rv.AttributeId in per_user for rv in items):
            return results
        role = self._sink.user_role(reader.user)
        for index, rv in enumerate(items):
            status = results[index].StatusCode
            if rv.AttributeId in per_user and (status is None or status.is_good()):
                answer = self._sink._user_attribute(rv.NodeId, rv.AttributeId, role)
                if answer is not None:
                    results[index] = answer
        return results

    async def write(self, params: ua.WriteParameters, user: User = _ADMIN) -> list[ua.StatusCode]:
        owned = self._sink._owned
        items = params.NodesToWrite
        if user is self._internal_user or not any(wv.NodeId in owned for wv in items):
            return await super().write(params, user)
        results: list[ua.StatusCode] = [ua.StatusCode()] * len(items)
        ours = [(i, wv) for i, wv in enumerate(items) if wv.NodeId in owned]
        others = [(i, wv) for i, wv in enumerate(items) if wv.NodeId not in owned]
        if others:
            theirs = await super().write(ua.WriteParameters(NodesToWrite=[wv for _, wv in others]), user)
            for (i, _), status in zip(others, theirs, strict=True):
                results[i] = status
        name, role = self._sink.user_name(user), self._sink.user_role(user)
        statuses = await asyncio.gather(*(self._sink._client_write(wv, name, role) for _, wv in ours))
        for (i, _), status in zip(ours, statuses, strict=True):
            results[i] = status
        return results


class OpcUaSink:
    """Mirrors the variable tree as an OPC UA server (implements gateway.sinks.base.Sink)."""

    name = "opcua"
    #: Our nodes go straight into asyncua's address space (bulk.py); False: through asyncua's AddNodes,
    #: as before (tests/integration/opcua/test_address_space_identity.py builds both and compares).
    direct_nodes = True
    #: Where the standard namespace is cached (gateway/shims/asyncua_ns0.py); None: built at every start.
    #: Used with `direct_nodes` only, so that the identity test compares a cached one with asyncua's own.
    cache_dir: Path | None = default_cache_dir()

    def __init__(
        self,
        tree: VariableTree,
        config: OpcUaServerConfig,
        state_dir: Path,
        users: UserDirectory | None = None,
        extensions: Sequence[ServerExtension] = (),
        redundant: RedundantSet | None = None,
    ) -> None:
        """`redundant`: with `shard: lease`, the fleet's servers as a non-transparent redundant set."""
        self.tree = tree
        self.redundant = redundant
        self.config = config
        self.state_dir = state_dir  # pki/ (own certificate, trusted/, rejected/) lives here
        self.pki = Pki(state_dir / "pki")
        self.users = users  # None: asyncua's own logins, without roles (tests of the sink alone)
        self.extensions = tuple(extensions)  # alarm conditions …: installed with the address space
        self.endpoint: str = config.endpoint
        self.namespace_index: int = -1
        self.application_uri = application_uri(shard_index())  # each shard of a fleet its own
        self.user_name: Callable[[Any], str | None] = session_user_name
        self.user_role: Callable[[Any], str | None] = session_user_role
        self.certificates: ClientCertificates | None = None
        self._methods: dict[ua.NodeId, tuple[Machine, Method]] = {}
        self._server: Server | None = None
        self._shared: SharedAttributes | None = None
        self._writer: NodeWriter | None = None
        self._plan: AddressSpacePlan | None = None
        self._sub: Subscription[VariableNode] | None = None
        self._vars: dict[VariableNode, _Variable] = {}
        self._by_id: dict[ua.NodeId, _Variable] = {}
        self._views: dict[VariableNode, list[_Variable]] = {}  # other nodes showing a variable (show)
        self._owned: set[ua.NodeId] = set()
        self._mismatched: set[VariableNode] = set()  # holding a value their type cannot carry
        self._unplaceable: set[VariableNode] = set()  # late variables the server refused
        self._failing: set[VariableNode] = set()  # whose last value write failed unexpectedly

    # --- seams for other components ----------------------------------------------------------

    @property
    def server(self) -> Server:
        if self._server is None:
            raise RuntimeError("the OPC UA sink is not started")
        return self._server

    @property
    def machines_node_id(self) -> ua.NodeId:
        return self._require_plan().machines_id

    def machine_node_id(self, machine: str) -> ua.NodeId:
        """The machine's Object, under which alarms, commands and programs attach."""
        if machine not in self.tree.machines:
            raise KeyError(f"no machine {machine!r}")
        return self._require_plan().machine_id(machine)

    def node_id(self, node: VariableNode) -> ua.NodeId:
        return self._require_plan().variable_id(node)

    async def add_nodes(self, items: Sequence[ua.AddNodesItem]) -> list[ua.NodeId]:
        """Add nodes in batches through the internal session; raises SinkError if any is refused."""
        writer = self._writer
        isession = self.server.iserver.isession
        added: list[ua.NodeId] = []
        for start in range(0, len(items), ADD_BATCH):
            chunk = list(items[start : start + ADD_BATCH])
            results = writer.add_nodes(chunk) if writer is not None else await isession.add_nodes(chunk)
            for item, result in zip(chunk, results, strict=True):
                if not result.StatusCode.is_good():
                    raise SinkError(
                        f"OPC UA server refused node {item.RequestedNewNodeId.to_string()}: "
                        f"{result.StatusCode.name}"
                    )
                added.append(result.AddedNodeId)
            if writer is None and self._shared is not None:
                self._shared.share(added[-len(chunk) :])
            await asyncio.sleep(0)
        return added

    # --- the ServerPort of extensions (port.py; alarm conditions: alarms.py) -------------------

    async def delete_nodes(self, nodeids: Sequence[ua.NodeId]) -> None:
        server = self.server
        await server.delete_nodes([server.get_node(nodeid) for nodeid in nodeids])

    async def add_event_notifier(self, nodeid: ua.NodeId) -> None:
        """Events may be subscribed on the object, and the Server object reports them too (HasNotifier)."""
        server = self.server
        mask = ua.EventNotifier.to_bitfield([ua.EventNotifier.SubscribeToEvents])
        notifier = ua.DataValue(ua.Variant(mask, ua.VariantType.Byte))
        await server.write_attribute_value(nodeid, notifier, ua.AttributeIds.EventNotifier)
        await server.get_node(SERVER_OBJECT).add_reference(
            nodeid, HAS_NOTIFIER, forward=True, bidirectional=True
        )

    def caller_context(self) -> WriteContext:
        """Who is calling, inside a method callback (asyncua does not pass the session to callbacks)."""
        caller = _CALLER.get()
        return WriteContext("opcua", self.user_name(caller), self.user_role(caller))

    def link_method(self, nodeid: ua.NodeId, callback: MethodCallback) -> None:
        """Serve calls of a Method node (also a standard one, such as Acknowledge) with `callback`."""
        self.server.iserver.isession.add_method_callback(nodeid, callback)

    async def trigger_event(
        self, event: Event, subscription: int | None = None, item: int | None = None
    ) -> None:
        """Report an event (an asyncua Event object) to its notifier's subscribers: all, or one subscription
        (and one of its monitored items), as ConditionRefresh does."""
        service = self.server.iserver.subscription_service
        if subscription is None:
            await service.trigger_event(event)
            return
        sub = service.subscriptions.get(subscription)
        if sub is None:
            return
        monitored = sub.monitored_item_srv
        if item is not None and item not in monitored._monitored_events.get(event.emitting_node, ()):
            return  # that item watches another notifier
        await monitored.trigger_event(event, item)

    async def trigger_unfiltered(self, event: Event, subscription: int, item: int | None = None) -> None:
        """Queue `event` for every event monitored item of one subscription (or only `item`), whatever its
        notifier and WhereClause: how OPC UA Part 9 (4.5) delivers RefreshStart/RefreshEnd events."""
        sub = self.server.iserver.subscription_service.subscriptions.get(subscription)
        if sub is None:
            return
        monitored = sub.monitored_item_srv
        for mids in list(monitored._monitored_events.values()):
            for mid in mids:
                mdata = monitored._monitored_items.get(mid)
                if mdata is None or (item is not None and mid != item):
                    continue
                fields = ua.EventFieldList(
                    ClientHandle=mdata.client_handle,
                    EventFields=event.to_event_fields(mdata.filter.SelectClauses),
                )
                await sub.enqueue_event(mid, fields, mdata.queue_size)

    def has_subscription(self, subscription: int) -> bool:
        return subscription in self.server.iserver.subscription_service.subscriptions

    async def import_nodesets(self, files: Sequence[Path]) -> None:
        """Load NodeSet2 files in order, from their cache after the first start (shims/asyncua_nodesets.py).
        asyncua's Python classes for their structures are not generated (the views write no such values)."""
        server = self.server
        started = time.perf_counter()

        async def import_one(path: Path) -> None:
            await server.import_xml(str(path), auto_load_definitions=False)

        cached = await import_nodesets(
            server, files, self.cache_dir if self.direct_nodes else None, import_one
        )
        log.info(
            "OPC UA: %d NodeSets %s in %.2f s",
            len(files),
            "loaded from their cache" if cached else "imported",
            time.perf_counter() - started,
        )

    async def register_namespace(self, uri: str) -> int:
        index: int = await self.server.register_namespace(uri)
        return index

    def namespace_of(self, uri: str) -> int:
        array = self.server.iserver.aspace.read_attribute_value(
            new_node_id(ua.ObjectIds.Server_NamespaceArray), ua.AttributeIds.Value
        )
        uris = array.Value.Value if array.Value is not None else []
        return uris.index(uri) if uri in uris else -1

    def references(self, nodeid: ua.NodeId) -> Sequence[ua.ReferenceDescription]:
        record = self.server.iserver.aspace._nodes.get(nodeid)
        return () if record is None else record.references

    def attribute(self, nodeid: ua.NodeId, attribute: ua.AttributeIds) -> ua.DataValue | None:
        record = self.server.iserver.aspace._nodes.get(nodeid)
        held = None if record is None else record.attributes.get(attribute)
        return None if held is None else held.value

    def show(self, nodeid: ua.NodeId, node: VariableNode, shown: Shown, *, writable: bool = False) -> None:
        """Serve `node`'s samples at `nodeid` too (a view's node): `_push` brings it the same sample in
        the same step as the variable's own node, lazily while nobody monitors it, as for our own."""
        held = self.server.iserver.aspace._nodes[nodeid].attributes[ua.AttributeIds.Value]
        view = _Variable(node, nodeid, shown, held)  # type: ignore[arg-type]
        self._views.setdefault(node, []).append(view)
        self._by_id[nodeid] = view
        if writable:
            self._owned.add(nodeid)

    async def set_value(self, nodeid: ua.NodeId, value: ua.DataValue) -> None:
        await self.server.iserver.aspace.write_attribute_value(nodeid, ua.AttributeIds.Value, value)

    # --- lifecycle ---------------------------------------------------------------------------

    async def __aenter__(self) -> Self:
        host, port = self._bind_address()
        _check_port_free(host, port, self.endpoint)
        started = time.perf_counter()
        with _gc_paused():
            await self._start()
        log.info(
            "OPC UA server listening on %s: %d variables in namespace %s (ns=%d), started in %.2f s",
            self.endpoint,
            len(self._vars),
            self.config.namespace,
            self.namespace_index,
            time.perf_counter() - started,
        )
        report_anonymous(self.users, self.tree, self.endpoint, self.config.endpoints)
        return self

    async def _start(self) -> None:
        self._vars, self._by_id, self._owned, self._views = {}, {}, set(), {}
        self._mismatched, self._unplaceable, self._failing = set(), set(), set()
        keep_written_values()  # no deep copy of every value per subscribed item (shims/asyncua_server.py)
        slim_attribute_values()  # slotted attribute records, no empty dict apiece (before init: ns0 too)
        forget_standard_namespace_code()  # the 12 MB of code that builds ns0, once it has run
        server = Server()
        server.name = self.config.name
        server.product_uri = "urn:cnc-gateway"
        server.manufacturer_name = "cnc-gateway"
        self._writer = NodeWriter(server.iserver) if self.direct_nodes else None
        service = server.iserver.node_mgt_service
        if (
            self._writer is not None
        ):  # asyncua's generated code builds the standard namespace, the writer adds it
            service.try_add_nodes = self._writer.try_add_nodes  # type: ignore[method-assign,assignment]
            if self.cache_dir is not None:  # built once, then read node by node from a file (asyncua_ns0.py)
                use_cache(server.iserver, self.cache_dir)
        try:
            await server.init()
        finally:
            vars(service).pop("try_add_nodes", None)
        self._shared = SharedAttributes(server)
        # The standard namespace (what is in memory of it): what this frees, our own nodes reuse.
        self._shared.share(loaded_node_ids(server.iserver.aspace._nodes))
        await server.set_application_uri(self.application_uri)
        if self.redundant is not None:
            await install_redundancy(server, self.redundant)
        await server.set_build_info(
            server.product_uri, server.manufacturer_name, self.config.name, __version__, "0", utcnow()
        )
        server.set_endpoint(self.endpoint)
        server.set_server_name(self.config.name)
        server.allow_remote_admin(False)  # no remote AddNodes/DeleteNodes through the "admin" user name
        self._set_identities(server)
        host = self._bind_address()[0]
        self.certificates = await secure_server(
            server, self.config.endpoints, self.pki, self.application_uri, self.config.name, host
        )
        self.namespace_index = await server.register_namespace(self.config.namespace)
        iserver = server.iserver
        iserver.attribute_service = _GatewayAttributeService(iserver.aspace, self, iserver.isession.user)
        _track_callers(iserver, lambda: server.bserver)
        iserver.max_monitored_item_queue_size = MAX_QUEUE_PER_ITEM
        self._server = server
        self._plan = AddressSpacePlan(self.namespace_index)
        # Subscribe before reading the initial samples, so no change falls between the two.
        self._sub = self.tree.hub.subscribe(self.name)
        try:
            await self._build()
            await server.start()
        except BaseException as exc:
            await self._close()
            self._server = self._plan = None
            if isinstance(exc, OSError):
                raise SinkError(
                    f"OPC UA server cannot listen on {self.endpoint}: {exc.strerror or exc}"
                ) from None
            raise

    def _set_identities(self, server: Server) -> None:
        """Which identity tokens the endpoints offer, and who checks them."""
        users = self.users
        if users is None:
            return  # asyncua's default: anonymous and user names, everyone accepted
        tokens: list[type] = []
        if users.anonymous_allowed:
            tokens.append(ua.AnonymousIdentityToken)
        if users.has_users:
            tokens.append(ua.UserNameIdentityToken)
            if not any(name != "None" for name in self.config.endpoints):
                log.warning(
                    "OPC UA: users are configured but only the None endpoint is offered: "
                    "passwords cross the network in clear text (opcua.profile: standard or secure)"
                )
        server.set_identity_tokens(tokens)
        server.iserver.set_user_manager(GatewayUserManager(users))

    async def __aexit__(self, *exc_info: object) -> None:
        await self._close()
        server, self._server = self._server, None
        if server is None:
            return
        iserver = server.iserver
        clock = iserver.time_task
        if clock is not None:
            # asyncua's clock task sleeps a whole second between ticks; stop it now, not then.
            clock.cancel()
            await asyncio.wait({clock})
            iserver.time_task = None
        await server.stop()
        log.info("OPC UA server on %s stopped", self.endpoint)

    async def _close(self) -> None:
        if self._sub is not None:
            self._sub.close()
            self._sub = None

    def health(self) -> SinkHealth:
        """Ready once the server listens (from the start: clients browse while controllers connect)."""
        return SinkHealth(ready=self._server is not None)

    async def run(self) -> None:
        """Mirror every change from the hub into the address space, until cancelled."""
        sub = self._sub
        if sub is None:
            raise RuntimeError("enter the OPC UA sink before running it")
        if self.redundant is None or self._server is None:
            await self._mirror(sub)
            return
        async with asyncio.TaskGroup() as group:
            group.create_task(keep_level(self._server, self.tree), name="sink:opcua:service-level")
            await self._mirror(sub)

    async def _mirror(self, sub: Subscription[VariableNode]) -> None:
        while True:
            batch = await sub.next_batch()
            await self._push(batch)

    # --- address space -----------------------------------------------------------------------

    def _require_plan(self) -> AddressSpacePlan:
        if self._plan is None:
            raise RuntimeError("the OPC UA sink is not started")
        return self._plan

    def _bind_address(self) -> tuple[str, int]:
        parts = urlsplit(self.endpoint)
        assert parts.hostname is not None and parts.port is not None  # checked by the config
        return parts.hostname, parts.port

    async def _build(self) -> None:
        plan = self._require_plan()
        methods: list[tuple[ua.NodeId, Method]] = []
        for machine in self.tree.machines.values():  # a machine at a time: its items never all exist at once
            plan.add_machines([machine])
            methods += plan_methods(plan, [machine])
            await self.add_nodes(plan.take())
            await asyncio.sleep(0)  # sources connect meanwhile (app.py): their replies are read here
        self._register(plan)
        owners = {id(m): machine for machine in self.tree.machines.values() for m in machine.methods.values()}
        for nodeid, method in methods:
            machine = owners[id(method)]
            self._methods[nodeid] = (machine, method)
            self.server.iserver.isession.add_method_callback(nodeid, self._method_callback(machine, method))
        for extension in self.extensions:
            await extension.install(self)
        await self._push([(node, node.sample) for node in self._vars])

    def _register(self, plan: AddressSpacePlan) -> None:
        records = self.server.iserver.aspace._nodes
        for node, nodeid in plan.variables.items():
            if node not in self._vars:
                held = records[nodeid].attributes[ua.AttributeIds.Value]
                var = _Variable(node, nodeid, value_kind(node.type), held)
                self._vars[node] = var
                self._by_id[nodeid] = var
        self._owned |= plan.owned
        plan.owned.clear()  # held here from now on: one set of 10,000 node ids, not two

    async def _place(self, node: VariableNode) -> _Variable | None:
        """A variable that appeared after start-up (a new internal variable, a new machine)."""
        if node in self._unplaceable:
            return None
        plan = self._require_plan()
        try:
            plan.add_variable(node)
            await self.add_nodes(plan.take())
        except Exception as exc:  # noqa: BLE001 - a refused node, whatever asyncua raised, must not stop the loop
            self._unplaceable.add(node)
            log.error("cannot add %s to the OPC UA address space: %s", node.full_path, exc)
            return None
        self._register(plan)
        return self._vars.get(node)

    # --- values ------------------------------------------------------------------------------

    async def _push(self, batch: list[Change[VariableNode]]) -> None:
        """Bring the address space up to `batch`.

        A variable no client monitors (asyncua keeps no data-change callback on its
        Value) only records the sample and the time: asyncua then answers a Read, or
        the first value of a monitored item created later, through `_read_value`,
        which builds the DataValue on demand. So the DataValue, its checks and
        asyncua's write path are paid only where a subscriber will see the change.
        """
        # asyncua's address space itself: Server's and InternalServer's write_attribute_value only pass it on.
        write = self.server.iserver.aspace.write_attribute_value
        value_attribute = ua.AttributeIds.Value
        mismatched = self._mismatched
        variables = self._vars
        read_value = self._read_value
        views = self._views
        now = utcnow()
        count = 0
        for node, sample in batch:
            if views and node in views:
                for view in views[node]:
                    await self._push_view(view, sample, now)
            var = variables.get(node)
            if var is None:
                var = await self._place(node)
                if var is None:
                    continue
            count += 1
            if count % YIELD_EVERY == 0:
                await asyncio.sleep(0)
                now = utcnow()
            held = var.held
            if not held.datachange_callbacks and held.value_setter is None:
                var.sample, var.pushed_at = sample, now
                if held.value_callback is not read_value:
                    held.value = None  # what asyncua's own set_attribute_value_callback does
                    held.value_callback = read_value
                continue
            if var.sample is not None:
                var.sample = var.pushed_at = None
            if mismatched:
                dv = self._datavalue(var, sample, now)
            else:
                try:
                    dv = var.kind.datavalue(sample, now)
                except ValueMismatch:
                    dv = self._datavalue(var, sample, now)  # says so once
            try:
                await write(
                    var.nodeid, value_attribute, dv
                )  # asyncua's path: monitored items compare and queue
            except Exception:  # not expected; one variable must not stop the others
                if node not in self._failing:
                    self._failing.add(node)
                    log.exception("cannot update %s in the OPC UA address space", node.full_path)

    async def _push_view(self, view: _Variable, sample: Sample, now: datetime) -> None:
        """One view's node (show): as `_push` does for our own, with the same sample and time."""
        held = view.held
        if not held.datachange_callbacks and held.value_setter is None:
            view.sample, view.pushed_at = sample, now
            if held.value_callback is not self._read_value:
                held.value = None
                held.value_callback = self._read_value
            return
        view.sample = view.pushed_at = None
        try:
            await self.server.iserver.aspace.write_attribute_value(
                view.nodeid, ua.AttributeIds.Value, self._datavalue(view, sample, now)
            )
        except Exception:  # not expected; one node must not stop the others
            if view.node not in self._failing:
                self._failing.add(view.node)
                log.exception("cannot update %s in the OPC UA address space", view.nodeid.to_string())

    def _datavalue(self, var: _Variable, sample: Sample, now: datetime) -> ua.DataValue:
        """The DataValue clients see for a sample (BadTypeMismatch, logged once, if it does not fit)."""
        node = var.node
        try:
            dv = var.kind.datavalue(sample, now)
        except ValueMismatch as exc:
            if node not in self._mismatched:
                self._mismatched.add(node)
                log.warning(
                    "%s holds %r, which OPC UA cannot carry as %s: %s",
                    node.full_path,
                    sample.value,
                    node.type,
                    exc,
                )
            return var.kind.mismatch(sample, now)
        if self._mismatched:
            self._mismatched.discard(node)
        return dv

    def _read_value(self, nodeid: ua.NodeId, attribute: Any) -> ua.DataValue:
        """asyncua's value callback for a variable nobody monitors: the last sample pushed, as a DataValue."""
        var = self._by_id[nodeid]
        sample, pushed_at = var.sample, var.pushed_at
        if sample is None or pushed_at is None:  # a monitored item was just created: not expected here
            sample, pushed_at = var.node.sample, utcnow()
        return self._datavalue(var, sample, pushed_at)

    # --- methods -----------------------------------------------------------------------------

    def _method_callback(self, machine: Machine, method: Method) -> Callable[..., Any]:
        """asyncua calls this with the object's node id and the input Variants."""

        async def callback(parent: ua.NodeId, *inputs: ua.Variant) -> ua.CallMethodResult:
            caller = _CALLER.get()
            return await call_result(machine, method, inputs, self.user_name(caller), self.user_role(caller))

        return callback

    def _user_attribute(self, nodeid: ua.NodeId, attribute: int, role: str | None) -> ua.DataValue | None:
        """UserAccessLevel of our variables, UserExecutable of our methods, for a session's role."""
        policy = self.tree.access
        if attribute == ua.AttributeIds.UserAccessLevel:
            var = self._by_id.get(nodeid)
            if var is None:
                return None
            if nodeid not in self._owned:  # a view's node that is not writable (show)
                return ua.DataValue(ua.Variant(ua.AccessLevel.CurrentRead.mask, ua.VariantType.Byte))
            level = user_access_level(var.node, role, policy)
            return ua.DataValue(ua.Variant(level, ua.VariantType.Byte))
        entry = self._methods.get(nodeid)
        if entry is None:
            return None
        return ua.DataValue(ua.Variant(user_executable(entry[1], role, policy), ua.VariantType.Boolean))

    # --- writes ------------------------------------------------------------------------------

    async def _client_write(self, wv: ua.WriteValue, user: str | None, role: str | None) -> ua.StatusCode:
        var = self._by_id.get(wv.NodeId)
        if var is None:  # one of our folders, objects or properties
            return new_status_code(ua.StatusCodes.BadNotWritable)
        status = await write_node(var.node, var.kind, wv, user, role)
        if status.is_good():  # read-your-writes: the controller's read-back is served before the answer
            await self._push([(var.node, var.node.sample)])
        return status


@contextmanager
def _gc_paused() -> Iterator[None]:
    """Hold off the cyclic garbage collector while the address space is built.

    Building creates about a million small objects next to the few hundred thousand
    of asyncua's standard address space, and the full collections this triggers
    took about half of the start-up time. Reference counting still frees what it
    can at once; only cyclic garbage waits for the first collection afterwards.
    """
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()


def _check_port_free(host: str, port: int, endpoint: str) -> None:
    """Fail with a clear SinkError when the port is taken, rather than asyncua's logged traceback."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as exc:
        raise SinkError(f"OPC UA endpoint {endpoint}: cannot resolve {host!r}: {exc.strerror}") from None
    for family, socktype, proto, _, addr in infos:
        try:
            probe = socket.socket(family, socktype, proto)
        except OSError:  # e.g. IPv6 disabled on this host; asyncio skips that family too
            continue
        with probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                probe.bind(addr)
            except OSError as exc:
                raise SinkError(f"OPC UA server cannot listen on {endpoint}: {exc.strerror or exc}") from None

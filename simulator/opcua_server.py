"""The simulator's OPC UA server: the PLC's variables, answering writes like a controller does.

asyncua's default attribute service answers every refused client write with
BadUserAccessDenied. A controller is more specific, and the gateway must cope
with what controllers say, so writes to our namespace go through
`_ControllerAttributeService`: BadNotWritable for read-only variables,
BadTypeMismatch for the wrong Variant type, and whatever the machine's command
raises (BadOutOfRange, BadInvalidState, BadInvalidArgument).

Values are pushed by `publish()`, which the runner calls every tick: only the
variables that changed are written, stamped with the machine's clock. Variables
marked `pushed` (benchmark noise, simulator/noise.py) are written by their own
driver through `server` instead.

A fleet (`cnc-simulator --machines N`, issue 29) serves every machine from one
server, `SharedOpcUa`: each machine's PLC tree in a folder named after it, its
node ids prefixed with that name (`ns=2;s=laser-001/::AsGlobalPV:…`), writes
routed to the machine that owns the node. One asyncua server per machine cost
about 40 MB and 1.5 s of start-up each.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import logging
from collections.abc import Callable, Iterable
from datetime import UTC, datetime
from typing import Any, Self

from asyncua import Server, ua
from asyncua.crypto.permission_rules import User, UserRole
from asyncua.server.address_space import AttributeService
from asyncua.server.user_managers import UserManager

from gateway.errors import RequestError
from gateway.shims.ua import new_data_value, new_node_id, new_status_code
from simulator.errors import SimulatorError
from simulator.machine import Machine
from simulator.variables import GLOBAL_FOLDER, NAMESPACE_URI, PLC_FOLDER, TASKS_FOLDER, Variable

log = logging.getLogger("simulator.opcua")

Clock = Callable[[], datetime]
_UNSET = object()


def utcnow() -> datetime:
    return datetime.now(UTC)


def variant_type(type_name: str) -> tuple[ua.VariantType, bool]:
    """`"UInt32[]"` -> (VariantType.UInt32, True)."""
    array = type_name.endswith("[]")
    return getattr(ua.VariantType, type_name.removesuffix("[]")), array


class _PasswordUsers(UserManager):
    """One user name and password; everything else (anonymous included) is refused."""

    def __init__(self, user: str, password: str) -> None:
        self.user = user
        self.password = password

    def get_user(
        self, iserver: Any, username: str | None = None, password: str | None = None, certificate: Any = None
    ) -> User | None:
        if username is None or password is None:
            return None
        if username == self.user and hmac.compare_digest(password.encode(), self.password.encode()):
            return User(role=UserRole.User, name=username)
        return None


class _ControllerAttributeService(AttributeService):
    """Client writes to the PLC namespace are judged by the variable table and the machine that owns the
    node (`owner`: the one machine of a server, or a fleet's machine by node id)."""

    def __init__(
        self, base: AttributeService, ns: int, owner: Callable[[ua.NodeId], PlcServer | None]
    ) -> None:
        super().__init__(base._aspace)
        self._ns = ns
        self._owner = owner

    async def write(self, params: ua.WriteParameters, user: User | None = None) -> list[ua.StatusCode]:
        user = user if user is not None else User(role=UserRole.Admin)
        results: list[ua.StatusCode] = []
        for wv in params.NodesToWrite:
            plc = self._owner(wv.NodeId) if wv.NodeId.NamespaceIndex == self._ns else None
            if plc is None and wv.NodeId.NamespaceIndex == self._ns and wv.NodeId not in self._aspace:
                results.append(new_status_code(ua.StatusCodes.BadNodeIdUnknown))
            elif plc is None:  # another namespace, or a node no machine owns yet (its folder being built)
                one = ua.WriteParameters()
                one.NodesToWrite = [wv]
                results.extend(await super().write(one, user))
            else:
                results.append(await plc.client_write(wv))
        return results


async def _stop_server(server: Server) -> None:
    # asyncua's clock task sleeps 1 s between updates; cancel it rather than wait for it.
    task = getattr(server.iserver, "time_task", None)
    if task is not None:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
        server.iserver.time_task = None
    await server.stop()


class SharedOpcUa:
    """One OPC UA server for a fleet of machines, each a `PlcServer(shared=…)` in a folder of its own.

    Async context manager: enter it before the machines, leave it after them."""

    def __init__(self, *, host: str = "127.0.0.1", port: int = 4841) -> None:
        self.host = host
        self.port = port
        self.ns = 2
        self._server: Server | None = None
        self._owners: dict[ua.NodeId, PlcServer] = {}

    @property
    def endpoint(self) -> str:
        return f"opc.tcp://{self.host}:{self.port}"

    @property
    def server(self) -> Server:
        if self._server is None:
            raise SimulatorError("the fleet's OPC UA server is not running")
        return self._server

    async def __aenter__(self) -> Self:
        server = Server()
        self._server = server
        await server.init()
        server.set_endpoint(self.endpoint)
        server.set_server_name("cnc-simulator fleet (simulated B&R-style PLCs, a folder per machine)")
        server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
        server.set_identity_tokens([ua.AnonymousIdentityToken])
        self.ns = await server.register_namespace(NAMESPACE_URI)
        base = server.iserver.attribute_service
        server.iserver.attribute_service = _ControllerAttributeService(base, self.ns, self._owners.get)
        try:
            await server.start()
        except OSError as exc:
            self._server = None
            await _stop_server(server)
            raise SimulatorError(
                f"OPC UA server cannot listen on {self.host}:{self.port}: {exc.strerror or exc}"
            ) from None
        if server.bserver is not None and self.port == 0:
            self.port = server.bserver.port or 0
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        server, self._server = self._server, None
        self._owners.clear()
        if server is not None:
            await _stop_server(server)

    def adopt(self, plc: PlcServer, nodes: Iterable[ua.NodeId]) -> None:
        for node in nodes:
            self._owners[node] = plc

    def forget(self, plc: PlcServer) -> None:
        for node in [n for n, owner in self._owners.items() if owner is plc]:
            del self._owners[node]


class PlcServer:
    """The PLC variables of one machine, in an asyncua Server of its own, or in a folder `folder` of a
    fleet's `shared` one. Async context manager."""

    def __init__(
        self,
        machine: Machine,
        variables: Iterable[Variable],
        *,
        host: str = "127.0.0.1",
        port: int = 4841,
        user: str | None = None,
        password: str | None = None,
        clock: Clock = utcnow,
        shared: SharedOpcUa | None = None,
        folder: str | None = None,
    ) -> None:
        if (user is None) != (password is None):
            raise ValueError("give both an OPC UA user and a password, or neither")
        if (shared is None) != (folder is None):
            raise ValueError("a machine on a shared OPC UA server needs a folder of its own, and only then")
        if shared is not None and user is not None:
            raise ValueError("a fleet's shared OPC UA server has no per-machine users")
        self._shared = shared
        self.folder = folder
        self._prefix = f"{folder}/" if folder else ""  # before each node id string
        self.machine = machine
        self.variables = list(variables)
        self.host = host
        self.port = port
        self._auth = (user, password) if user is not None and password is not None else None
        self._clock = clock
        self._server: Server | None = None
        self.ns = 2
        self._by_id: dict[ua.NodeId, tuple[Variable, ua.VariantType, bool]] = {}
        self._polled: dict[ua.NodeId, tuple[Variable, ua.VariantType, bool]] = {}  # publish() reads these
        self._objects: set[ua.NodeId] = set()
        self._cache: dict[ua.NodeId, Any] = {}
        self._lock = asyncio.Lock()

    @property
    def endpoint(self) -> str:
        return f"opc.tcp://{self.host}:{self.port}"

    @property
    def server(self) -> Server:
        """The running asyncua Server, for drivers that push values themselves (noise mode)."""
        if self._server is None:
            raise SimulatorError("the OPC UA server is not running")
        return self._server

    async def __aenter__(self) -> Self:
        if self._shared is not None:
            shared = self._shared
            self._server, self.ns = shared.server, shared.ns
            self.host, self.port = shared.host, shared.port
            await self._build()
            shared.adopt(self, [*self._by_id, *self._objects])
            await self.publish()
            return self
        users = _PasswordUsers(*self._auth) if self._auth else None
        server = Server(user_manager=users)
        self._server = server
        await server.init()
        server.set_endpoint(f"opc.tcp://{self.host}:{self.port}")
        server.set_server_name("cnc-simulator (simulated B&R-style PLC)")
        server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
        server.set_identity_tokens([ua.UserNameIdentityToken] if self._auth else [ua.AnonymousIdentityToken])
        self.ns = await server.register_namespace(NAMESPACE_URI)
        await self._build()
        base = server.iserver.attribute_service
        server.iserver.attribute_service = _ControllerAttributeService(base, self.ns, lambda _node: self)
        try:
            await server.start()
        except OSError as exc:
            await self._stop()
            raise SimulatorError(
                f"OPC UA server cannot listen on {self.host}:{self.port}: {exc.strerror or exc}"
            ) from None
        if server.bserver is not None and self.port == 0:
            self.port = server.bserver.port or 0
        await self.publish()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self._stop()

    async def _stop(self) -> None:
        server = self._server
        if server is None:
            return
        self._server = None
        if self._shared is not None:  # the fleet's server stays up for the others; its nodes go with it
            self._shared.forget(self)
            return
        await _stop_server(server)

    # --- address space -------------------------------------------------------------------------

    async def _build(self) -> None:
        assert self._server is not None
        ns, prefix = self.ns, self._prefix
        root = self._server.nodes.objects
        if self.folder is not None:
            root = await root.add_folder(new_node_id(self.folder, ns), ua.QualifiedName(self.folder, ns))
        plc = await root.add_folder(new_node_id(prefix + PLC_FOLDER, ns), ua.QualifiedName("PLC", ns))
        nodes = {PLC_FOLDER: plc}
        for folder_id, name in ((GLOBAL_FOLDER, "Global"), (TASKS_FOLDER, "Tasks")):
            nodes[folder_id] = await plc.add_folder(
                new_node_id(prefix + folder_id, ns), ua.QualifiedName(name, ns)
            )
        self._objects = {n.nodeid for n in nodes.values()}
        if root is not self._server.nodes.objects:
            self._objects.add(root.nodeid)
        for var in self.variables:
            parent = plc
            for node_id, name in var.ancestors:
                if node_id not in nodes:
                    nodes[node_id] = await parent.add_object(
                        new_node_id(prefix + node_id, ns), ua.QualifiedName(name, ns)
                    )
                    self._objects.add(nodes[node_id].nodeid)
                parent = nodes[node_id]
            vtype, array = variant_type(var.type)
            initial = var.read(self.machine)
            node = await parent.add_variable(
                new_node_id(prefix + var.node_id, ns),
                ua.QualifiedName(var.name, ns),
                ua.Variant(initial, vtype, is_array=array),
                datatype=ua.NodeId(getattr(ua.ObjectIds, vtype.name)),
            )
            if array:
                await node.write_attribute(
                    ua.AttributeIds.ValueRank, ua.DataValue(ua.Variant(1, ua.VariantType.Int32))
                )
                dims = ua.Variant([var.array_length], ua.VariantType.UInt32)
                await node.write_attribute(ua.AttributeIds.ArrayDimensions, ua.DataValue(dims))
            if var.description:
                text = ua.Variant(ua.LocalizedText(var.description), ua.VariantType.LocalizedText)
                await node.write_attribute(ua.AttributeIds.Description, ua.DataValue(text))
            if var.writable:
                await node.set_writable()
            self._by_id[node.nodeid] = (var, vtype, array)  # the first publish stamps every value
            if not var.pushed:
                self._polled[node.nodeid] = (var, vtype, array)

    # --- values --------------------------------------------------------------------------------

    async def publish(self, *, skip: ua.NodeId | None = None) -> None:
        """Write every variable whose value changed since the last publish, stamped with the machine clock."""
        server = self._server
        if server is None:
            return
        async with self._lock:
            stamp = self._clock()
            for node_id, (var, vtype, array) in self._polled.items():
                if node_id == skip:
                    continue
                value = var.read(self.machine)
                if self._cache.get(node_id, _UNSET) == value:
                    continue
                self._cache[node_id] = value
                dv = new_data_value(
                    ua.Variant(value, vtype, is_array=array), SourceTimestamp=stamp, ServerTimestamp=utcnow()
                )
                await server.write_attribute_value(node_id, dv)

    async def client_write(self, wv: ua.WriteValue) -> ua.StatusCode:
        """Judge one client write to the PLC namespace like a controller, and carry it out."""
        entry = self._by_id.get(wv.NodeId)
        if entry is None:
            if wv.NodeId in self._objects:
                return new_status_code(ua.StatusCodes.BadNotWritable)
            return new_status_code(ua.StatusCodes.BadNodeIdUnknown)
        var, vtype, array = entry
        if wv.AttributeId != ua.AttributeIds.Value or var.write is None:
            return new_status_code(ua.StatusCodes.BadNotWritable)
        if wv.IndexRange:
            return new_status_code(ua.StatusCodes.BadWriteNotSupported)
        variant = wv.Value.Value if wv.Value is not None else None
        if (
            variant is None
            or variant.VariantType != vtype
            or bool(variant.is_array) != array
            or variant.Value is None
        ):
            got = "null" if variant is None else variant.VariantType.name + ("[]" if variant.is_array else "")
            log.info("write to %s refused: expected %s, got %s", var.node_id, var.type, got)
            return new_status_code(ua.StatusCodes.BadTypeMismatch)
        try:
            var.write(self.machine, variant.Value)
        except RequestError as exc:
            log.info("write %s = %r refused: %s (%s)", var.node_id, variant.Value, exc.reason, exc.status)
            return new_status_code(getattr(ua.StatusCodes, exc.status, ua.StatusCodes.BadInternalError))
        log.info("write %s = %r accepted", var.node_id, variant.Value)
        async with self._lock:
            # Show what the client wrote (a command bit reads true) until the next tick
            # puts the machine's own value back, as a PLC cycle would.
            stamp = self._clock()
            dv = new_data_value(variant, SourceTimestamp=stamp, ServerTimestamp=utcnow())
            assert self._server is not None
            await self._server.write_attribute_value(wv.NodeId, dv)
            self._cache[wv.NodeId] = _UNSET
        await self.publish(skip=wv.NodeId)  # the command's effects show at once
        return new_status_code(ua.StatusCodes.Good)

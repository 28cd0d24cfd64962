"""The OPC UA driver: a controller with an OPC UA server (client.py), and `cnc-gateway discover
opc.tcp://…` (discover.py), which browses one and writes a starting mapping file.

The folder is the driver: its settings (config.py), the one adapter of asyncua (client.py with
publish_decode.py and its C reader _publish.c, status.py, asyncua_logs.py), the discovery helpers.
"""

from __future__ import annotations

from gateway.codecs.opcua_nodeid import parse_address
from gateway.model.tree import Machine
from gateway.sources.base import DiscoverRequest, DriverMapping, DriverSpec, Source
from gateway.sources.opcua.config import OpcUaDriver


def _create(machine: Machine, mapping: DriverMapping) -> Source:
    from gateway.sources.opcua.client import OpcUaSource  # asyncua loads only when a machine uses it

    return OpcUaSource(machine, mapping)


async def _discover(request: DiscoverRequest) -> str:
    from gateway.sources.opcua.discover import discover

    return await discover(
        request.endpoint,
        machine=request.machine,
        username=request.user,
        password=request.password,
        security=request.security,
        start=request.start,
        max_depth=request.max_depth,
        max_variables=request.max_variables,
        timeout=request.timeout,
    )


SPEC = DriverSpec(
    type="opcua",
    settings=OpcUaDriver,
    create=_create,
    summary="a controller's OPC UA server: subscriptions, writes with read-back (asyncua)",
    check_address=parse_address,  # ns=2;s=… node ids and browse paths, checked at load time
    discover=_discover,  # the default driver's: any endpoint no other driver's `discovers` names
)

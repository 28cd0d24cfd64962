"""MTConnect in, two drivers of one folder: machines read from another agent (`type: mtconnect`,
agent_source.py) or straight from an SHDR adapter (`type: shdr`, shdr_source.py); both turn the
standard's text into the variables' types through values.py. `discover.py` writes a starting mapping
from an agent's /probe."""

from __future__ import annotations

from gateway.model.tree import Machine
from gateway.sources.base import DiscoverRequest, DriverMapping, DriverSpec, Source
from gateway.sources.mtconnect.config import MTConnectDriver, ShdrDriver

READ_ONLY = "MTConnect has no writes"


def _agent(machine: Machine, mapping: DriverMapping) -> Source:
    from gateway.sources.mtconnect.agent_source import MTConnectSource

    return MTConnectSource(machine, mapping)


def _adapter(machine: Machine, mapping: DriverMapping) -> Source:
    from gateway.sources.mtconnect.shdr_source import ShdrSource

    return ShdrSource(machine, mapping)


async def _discover(request: DiscoverRequest) -> str:
    from gateway.sources.mtconnect.discover import discover_agent

    return await discover_agent(
        request.endpoint, machine=request.machine, device=request.device, wait=request.timeout
    )


AGENT = DriverSpec(
    type="mtconnect",
    settings=MTConnectDriver,
    create=_agent,
    summary="another MTConnect agent: /probe, then a /sample stream (read-only)",
    read_only=READ_ONLY,
    discovers=("http://", "https://"),
    discover=_discover,
)
SHDR = DriverSpec(
    type="shdr",
    settings=ShdrDriver,
    create=_adapter,
    summary="an MTConnect adapter straight over TCP (SHDR; read-only)",
    read_only=READ_ONLY,
)

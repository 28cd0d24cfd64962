"""The FOCAS2 Ethernet driver (`driver: {type: focas}`): a Fanuc read and written without Fwlib.

config.py its settings; session.py, pool.py and transfer.py the asyncio client (a session, a pool of
at most N, program transfer), which the FOCAS delivery transport (gateway/transports/focas/)
shares; source.py the driver (poll groups, changes only, checked writes); discover.py
`cnc-gateway discover focas://host:8193`. The protocol's parsing is gateway/codecs/focas/.
"""

from __future__ import annotations

from gateway.codecs.focas.address import parse_address
from gateway.model.tree import Machine
from gateway.sources.base import DiscoverRequest, DriverMapping, DriverSpec, Source
from gateway.sources.focas.config import FocasDriver


def _create(machine: Machine, mapping: DriverMapping) -> Source:
    from gateway.sources.focas.source import FocasSource

    return FocasSource(machine, mapping)


async def _discover(request: DiscoverRequest) -> str:
    from gateway.sources.focas.discover import discover_focas

    return await discover_focas(request.endpoint, machine=request.machine, timeout=request.timeout)


SPEC = DriverSpec(
    type="focas",
    settings=FocasDriver,
    create=_create,
    summary="a Fanuc over FOCAS2 Ethernet (port 8193): status, positions, macros, PMC, alarms, programs",
    check_address=parse_address,
    discovers=("focas://",),
    discover=_discover,
)

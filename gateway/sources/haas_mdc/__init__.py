"""The Haas NGC machine data collection driver (`driver: {type: haas-mdc}`): Q-commands, ?E macro writes.

config.py its settings; connection.py the one asyncio connection (answers matched by label, the
others counted); source.py the driver. The protocol's parsing is gateway/codecs/haas_mdc/.
"""

from __future__ import annotations

from gateway.codecs.haas_mdc.protocol import parse_address
from gateway.model.tree import Machine
from gateway.sources.base import DriverMapping, DriverSpec, Source
from gateway.sources.haas_mdc.config import HaasMdcDriver


def _create(machine: Machine, mapping: DriverMapping) -> Source:
    from gateway.sources.haas_mdc.source import HaasMdcSource

    return HaasMdcSource(machine, mapping)


SPEC = DriverSpec(
    type="haas-mdc",
    settings=HaasMdcDriver,
    create=_create,
    summary="a Haas NGC over machine data collection (Setting 143): Q-commands, ?E macro writes",
    check_address=parse_address,
)

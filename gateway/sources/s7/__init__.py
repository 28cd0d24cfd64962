"""The Siemens S7 driver (`driver: {type: s7, host, rack, slot, …}`): `config.py` its settings and the
checks of a mapping's sources, `link.py` the one module that imports python-snap7 (the ISO-on-TCP
connection and the PDU negotiation), `source.py` the multi-variable reads and the writes, `cli.py`
`cnc-gateway s7 read`. Addresses, types and the Read Var/Write Var PDUs are pure: gateway/codecs/s7/."""

from __future__ import annotations

from gateway.codecs.s7.address import parse_address
from gateway.model.tree import Machine
from gateway.sources.base import DriverMapping, DriverSpec, Source
from gateway.sources.s7.config import S7Driver


def _create(machine: Machine, mapping: DriverMapping) -> Source:
    from gateway.sources.s7.source import S7Source

    return S7Source(machine, mapping)


SPEC = DriverSpec(
    type="s7",
    settings=S7Driver,
    create=_create,
    summary="a Siemens S7 PLC (S7-300/400/1200/1500, a SINUMERIK's PLC): data blocks, flags, inputs, outputs",
    check_address=parse_address,
    commands=(("s7", "gateway.sources.s7.cli"),),
)

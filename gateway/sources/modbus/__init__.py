"""The Modbus TCP driver (`driver: {type: modbus, host, port, unit, …}`): `config.py` its settings and the
checks of a mapping's sources, `link.py` the one module that imports pymodbus (errors translated there),
`source.py` the polling groups and writes, `cli.py` `cnc-gateway modbus scan` (docs/architecture.md,
"Modbus TCP"). The addresses, layouts and the request planner are pure: gateway/codecs/modbus/."""

from __future__ import annotations

from gateway.codecs.modbus.address import parse_address
from gateway.model.tree import Machine
from gateway.sources.base import DriverMapping, DriverSpec, Source
from gateway.sources.modbus.config import ModbusDriver


def _create(machine: Machine, mapping: DriverMapping) -> Source:
    from gateway.sources.modbus.source import ModbusSource

    return ModbusSource(machine, mapping)


SPEC = DriverSpec(
    type="modbus",
    settings=ModbusDriver,
    create=_create,
    summary="a Modbus TCP device (laser source, chiller, extractor, loader): polled registers and coils",
    check_address=parse_address,
    commands=(("modbus", "gateway.sources.modbus.cli"),),
)

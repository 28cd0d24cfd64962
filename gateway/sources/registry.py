"""The drivers: one line per driver folder. Adding a driver is its folder and its line here.

The drivers of this repository are a static table: the import contracts (pyproject.toml) then see every
edge from the configuration to a driver, mypy checks every spec, and a driver needs no install step. A
driver shipped as a package of its own adds itself without a line here, through the entry point group
`cnc_gateway.drivers` (name: its type, value: `module:SPEC`), read once when this module is imported
(docs/architecture.md, "The registry").
"""

from __future__ import annotations

from gateway.model.tree import Machine
from gateway.plugins import installed
from gateway.sources.base import DriverMapping, DriverSpec, Source
from gateway.sources.focas import SPEC as FOCAS
from gateway.sources.haas_mdc import SPEC as HAAS_MDC
from gateway.sources.modbus import SPEC as MODBUS
from gateway.sources.mtconnect import AGENT as MTCONNECT
from gateway.sources.mtconnect import SHDR
from gateway.sources.opcua import SPEC as OPCUA
from gateway.sources.s7 import SPEC as S7

BUILT_IN: tuple[DriverSpec, ...] = (
    FOCAS,
    HAAS_MDC,
    MODBUS,
    MTCONNECT,
    OPCUA,
    S7,
    SHDR,
)

GROUP = "cnc_gateway.drivers"
DRIVERS: tuple[DriverSpec, ...] = BUILT_IN + installed(GROUP, DriverSpec, BUILT_IN, lambda spec: spec.type)

# The driver of a `driver:` section without a `type` (mapping files from before the other drivers).
DEFAULT = OPCUA.type


def ordered() -> tuple[DriverSpec, ...]:
    """The drivers in the order users see them (schema, error messages): the default, then by type."""
    return tuple(sorted(DRIVERS, key=lambda spec: (spec.type != DEFAULT, spec.type)))


def types() -> tuple[str, ...]:
    return tuple(spec.type for spec in ordered())


def find(type_name: str) -> DriverSpec | None:
    """The driver of `driver.type`, None if no driver has that type."""
    return next((spec for spec in DRIVERS if spec.type == type_name), None)


def create_source(machine: Machine, mapping: DriverMapping) -> Source:
    """The source of one machine, by its mapping's `driver.type` (the loader refuses unknown types)."""
    spec = find(mapping.driver.type)
    if spec is None:
        raise ValueError(f"unknown driver type {mapping.driver.type!r}")
    return spec.create(machine, mapping)

"""The delivery transports: one line per transport folder. Adding a transport is its folder and its line
here.

A machine's `jobs.controller` section says how its controller takes programs; its `type` picks the
transport here (`ftp` when it has none: files from before serial DNC). The mapping file's union of
controller models is built from this table (gateway/config/jobs.py), so that the schema and the
loader's errors know every transport. Packages of their own add transports through the entry point
group `cnc_gateway.transports` (name: its type, value: `module:SPEC`); see gateway/sources/registry.py
for why the table is static.
"""

from __future__ import annotations

from gateway.plugins import installed
from gateway.transports.base import OpenStore, TransportSpec
from gateway.transports.dnc import SPEC as SERIAL
from gateway.transports.focas import SPEC as FOCAS
from gateway.transports.ftp import SPEC as FTP

BUILT_IN: tuple[TransportSpec, ...] = (
    FTP,
    SERIAL,
    FOCAS,
)

GROUP = "cnc_gateway.transports"
TRANSPORTS: tuple[TransportSpec, ...] = BUILT_IN + installed(
    GROUP, TransportSpec, BUILT_IN, lambda spec: spec.type
)

# The transport of a `controller:` section without a `type` (mapping files from before serial DNC).
DEFAULT = FTP.type


def ordered() -> tuple[TransportSpec, ...]:
    """The transports in the order users see them (schema, error messages): the table's."""
    return TRANSPORTS


def types() -> tuple[str, ...]:
    return tuple(spec.type for spec in TRANSPORTS)


def find(type_name: str) -> TransportSpec:
    """The transport of `jobs.controller.type` (the loader refuses unknown types: a miss is a bug)."""
    spec = next((spec for spec in TRANSPORTS if spec.type == type_name), None)
    if spec is None:
        raise TypeError(f"no delivery transport of type {type_name!r}")
    return spec


def program_store_for(controller: object) -> OpenStore | None:
    """Opens a session with the program store of a machine whose `jobs.controller` this is; None where
    the transport has no store to look into (a serial line only sends)."""
    spec = find(str(getattr(controller, "type", DEFAULT)))
    return None if spec.store is None else spec.store(controller)

"""The sinks: one line per sink folder. Adding a sink is its folder and its line here.

Built in this order (and entered in it, and run): a sink that offers others a port comes before the
sinks that take it (the OPC UA server's trust list before the console), and the console last, as it
shows the others. Packages of their own add sinks through the entry point group `cnc_gateway.sinks`
(after these); see gateway/sources/registry.py for why the table is static.
"""

from __future__ import annotations

from gateway.plugins import installed
from gateway.settings.sections import Section
from gateway.sinks.base import SinkSpec
from gateway.sinks.copydata import SPEC as COPYDATA
from gateway.sinks.mqtt import SPEC as MQTT
from gateway.sinks.mtconnect import SPEC as MTCONNECT
from gateway.sinks.opcua import SPEC as OPCUA
from gateway.sinks.sparkplug import SPEC as SPARKPLUG
from gateway.sinks.web import SPEC as WEB

BUILT_IN: tuple[SinkSpec, ...] = (
    OPCUA,
    MQTT,
    SPARKPLUG,
    COPYDATA,
    MTCONNECT,
)

GROUP = "cnc_gateway.sinks"
SINKS: tuple[SinkSpec, ...] = (
    *BUILT_IN,
    *installed(GROUP, SinkSpec, (*BUILT_IN, WEB), lambda spec: spec.name),
    WEB,  # last: it shows the others
)


def gateway_sections() -> tuple[Section, ...]:
    """The gateway file's keys the sinks own."""
    return tuple(spec.section for spec in SINKS if spec.section is not None)


def machine_sections() -> tuple[Section, ...]:
    """The mapping file's keys per machine the sinks (and the OPC UA server's extensions) own."""
    return tuple(section for spec in SINKS for section in spec.machine_sections)


def variable_sections() -> tuple[Section, ...]:
    return tuple(section for spec in SINKS for section in spec.variable_sections)

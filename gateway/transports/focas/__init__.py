"""The FOCAS delivery transport (`jobs.controller: {type: focas}`): programs into a Fanuc's CNC memory or
data server folder over FOCAS2, with the FOCAS driver's client (gateway/sources/focas/).

config.py its settings; transport.py the transport and the program store. The driver's own settings
(`driver: {type: focas}`) stay with the driver.
"""

from __future__ import annotations

from collections.abc import Sequence

from gateway.transports.base import (
    CorePorts,
    Deliveries,
    Delivery,
    EachMachine,
    MachineJobs,
    OpenStore,
    TransportSpec,
    settings_of,
)
from gateway.transports.focas.config import ControllerFocas


def assemble(machines: Sequence[MachineJobs], _core: CorePorts) -> Deliveries:
    from gateway.transports.focas.transport import FocasTransport

    built = {}
    for m in machines:
        config = settings_of(m.jobs.controller, ControllerFocas)
        transport = FocasTransport(config, verify=m.jobs.verify)
        # No `folder` for auto-start's `select_value: path`: a Fanuc selects by program name.
        built[m.name] = Delivery(transport, store=FocasTransport(config).store)
    return EachMachine(built)


def store(settings: object) -> OpenStore:
    from gateway.transports.focas.transport import FocasTransport

    return FocasTransport(settings_of(settings, ControllerFocas)).store


SPEC = TransportSpec(
    type="focas",
    settings=ControllerFocas,
    assemble=assemble,
    store=store,
    summary="a Fanuc's program memory over FOCAS2 (the FOCAS driver's client): put, verify, list, fetch",
)

"""The FTP delivery transport (`jobs.controller: {type: ftp}`, the default): the controller's FTP program
store, over aioftp.

config.py its settings; transport.py the transport and the program store (`Programs` methods,
`cnc-gateway programs`). Its library is imported when a machine uses it, not when a file is loaded.
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
from gateway.transports.ftp.config import ControllerFtp


def assemble(machines: Sequence[MachineJobs], _core: CorePorts) -> Deliveries:
    from gateway.transports.ftp.transport import FtpTransport

    built = {}
    for m in machines:
        config = settings_of(m.jobs.controller, ControllerFtp)
        transport = FtpTransport(config, verify=m.jobs.verify)
        built[m.name] = Delivery(transport, store=FtpTransport(config).store, folder=config.folder)
    return EachMachine(built)


def store(settings: object) -> OpenStore:
    from gateway.transports.ftp.transport import FtpTransport

    return FtpTransport(settings_of(settings, ControllerFtp)).store


SPEC = TransportSpec(
    type="ftp",
    settings=ControllerFtp,
    assemble=assemble,
    store=store,
    summary="the controller's FTP program store (aioftp): upload, verify, list, fetch, delete",
)

"""The delivery transports, one module each, and the choice of one per machine from its mapping file.

A machine's `jobs.controller` section says how its controller takes programs; its
type picks the transport: the controller's FTP store (`ControllerFtp`,
transports/ftp.py) or a serial DNC line (`ControllerSerial`, transports/serial.py).
A new transport adds its settings model to gateway/config/jobs.py and one branch
to each function here (docs/architecture.md, "Adding a delivery transport").
"""

from __future__ import annotations

from pathlib import Path

from gateway.config.focas import ControllerFocas
from gateway.config.jobs import ControllerFtp, ControllerSerial, JobsConfig
from gateway.jobs.delivery.transport import DeliveryTransport, OpenStore
from gateway.jobs.delivery.transports.focas import FocasTransport
from gateway.jobs.delivery.transports.ftp import FtpTransport
from gateway.jobs.delivery.transports.serial import SerialTransport
from gateway.jobs.dnc.transfers import TransferLog


def transport_for(
    jobs: JobsConfig,
    *,
    machine: str = "",
    state_dir: Path | None = None,
    transfer_log: TransferLog | None = None,
) -> DeliveryTransport:
    """How programs reach this machine's controller."""
    controller = jobs.controller
    if isinstance(controller, ControllerFtp):
        return FtpTransport(controller, verify=jobs.verify)
    if isinstance(controller, ControllerSerial):
        return SerialTransport(controller, machine=machine, state_dir=state_dir, transfer_log=transfer_log)
    if isinstance(controller, ControllerFocas):
        return FocasTransport(controller, verify=jobs.verify)
    # A settings model without its branch here: a bug, not a configuration error.
    raise TypeError(f"no delivery transport for {type(controller).__name__}")


def program_store_for(jobs: JobsConfig) -> OpenStore | None:
    """Opens a session with this machine's program store; None where the transport has no store to look
    into (a serial line only sends)."""
    controller = jobs.controller
    if isinstance(controller, ControllerFtp):
        return FtpTransport(controller).store
    if isinstance(controller, ControllerFocas):
        return FocasTransport(controller).store
    return None

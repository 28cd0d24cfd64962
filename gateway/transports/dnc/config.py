"""The serial DNC transport's settings: `jobs.controller: {type: serial, where, ...}`.

The line's own settings (port, framing, drip-feed); what the gateway does with what the
machine sends between jobs (`jobs.punch`) is punch.py.
"""

from __future__ import annotations

import re
from typing import Literal

from pydantic import Field, field_validator, model_validator

from gateway.settings.base import Strict
from gateway.settings.names import check_variable_path

_URL = re.compile(r"^(socket|rfc2217)://([A-Za-z0-9_.\-]+|\[[0-9A-Fa-f:.]+\]):(\d{1,5})/?$")
_DEVICE = re.compile(r"^(/dev/[A-Za-z0-9_.\-/]+|COM[0-9]{1,3}|\\\\\.\\COM[0-9]{1,3})$")


class AlarmWhen(Strict):
    """A mapped variable whose value says the controller is in alarm (a drip-feed then stops, FAILED)."""

    path: str = Field(description="Mapped variable, e.g. Machine/State")
    equals: bool | int | float | str = Field(description="The value that means alarm, e.g. 3")

    @field_validator("path")
    @classmethod
    def _path(cls, path: str) -> str:
        return check_variable_path(path)


class ControllerSerial(Strict):
    """A controller that takes programs over RS-232 (serial DNC), directly or through a device server."""

    type: Literal["serial"] = Field(description="serial: RS-232 DNC (load or drip-feed)")
    where: str = Field(
        description="A device path (/dev/ttyUSB0, COM3), rfc2217://host:port (a device server with "
        "RFC 2217) or socket://host:port (a raw TCP device server)"
    )
    baud: int = Field(default=9600, ge=50, le=4_000_000, description="Line speed, bits per second")
    bytesize: Literal[7, 8] = Field(default=7, description="Data bits (Fanuc: 7)")
    parity: Literal["none", "even", "odd"] = Field(default="even", description="Parity bit")
    stopbits: Literal[1, 2] = Field(default=2, description="Stop bits")
    handshake: Literal["xonxoff", "rtscts", "none"] = Field(
        default="xonxoff", description="Flow control: the controller's DC1/DC3 (xonxoff), RTS/CTS, or none"
    )
    eob: Literal["lf", "crlf"] = Field(default="lf", description="End of block the controller expects")
    leader: int = Field(default=20, ge=0, le=10_000, description="NULs sent before the first %")
    percent: bool = Field(default=True, description="Frame the program with % markers")
    chunk_size: int = Field(default=200, ge=1, le=65_536, description="Most bytes handed to the port at once")
    software_parity: bool = Field(
        default=False,
        description="Send a 7-bit line's parity bit as bit 7 of 8-bit bytes: only for a transparent 8-bit "
        "port (a device server whose serial port is set to 8N1/8N2, a pseudo-terminal). A device server "
        "whose port is set to the controller's format (7E2: the usual set-up) does the parity itself: "
        "leave it off. DC1/DC3 are obeyed whatever their bit 7 either way (docs/dnc-fanuc.md)",
    )
    mode: Literal["load", "drip"] = Field(
        default="load",
        description="load: the whole program into the controller's memory; drip: it runs as it arrives",
    )
    start: Literal["dc1", "now"] = Field(
        default="dc1", description="Start sending on the controller's first DC1 (its READ), or at once"
    )
    dc1_timeout: float = Field(
        default=60.0, gt=0, description="Seconds to wait for the controller's DC1 before the job fails"
    )
    stall_timeout: float = Field(
        default=600.0,
        gt=0,
        description="Seconds the controller may hold the line with DC3 before the job fails "
        "(a machine in feed hold)",
    )
    lead_time: float = Field(
        default=30.0, gt=0, description="Drip: seconds of cutting the controller's buffer should hold ahead"
    )
    buffer: int = Field(
        default=256, ge=8, le=16 * 1024 * 1024, description="The controller's receive buffer, bytes"
    )
    link: str | None = Field(
        default=None,
        pattern=r"^[A-Za-z0-9_.:-]{1,64}$",
        description="Drip: the device server or uplink this line shares with other machines' lines (any "
        "name; the same name in each machine's file); with link_capacity, the lines share it so that the "
        "machine whose buffer runs dry first is served first",
    )
    link_capacity: float | None = Field(
        default=None,
        gt=0,
        description="Characters per second the shared link carries for all its lines together",
    )
    rapid: float = Field(
        default=10_000.0, gt=0, description="Rapid rate, mm/min, for the run-time estimate while dripping"
    )
    lathe: bool = Field(
        default=False,
        description="Drip: the programs are a lathe's (Fanuc T, G-code system A: X a diameter, G98/G99 feed "
        "per minute/revolution, G50 S the spindle clamp), for the run-time estimate",
    )
    dwell_p: Literal["ms", "s"] = Field(
        default="ms",
        description="Drip: the unit of G4 P in the run-time estimate (Fanuc: ms; LinuxCNC: s). The "
        "estimate errs short, so ms is the default",
    )
    connect_timeout: float = Field(default=10.0, gt=0, description="Seconds to open the port")
    alarm_when: AlarmWhen | None = Field(
        default=None,
        description="A serial line cannot tell that the controller went into alarm; where the machine's "
        "state is mapped (from another driver), this stops a transfer when it says alarm",
    )
    dsr: bool = Field(
        default=False,
        description="A device path only: fail the transfer when DSR drops (the cable has DSR wired)",
    )

    @field_validator("where")
    @classmethod
    def _where(cls, where: str) -> str:
        if "://" in where:
            match = _URL.match(where)
            if match is None:
                raise ValueError(f"{where!r} is not like socket://host:port or rfc2217://host:port")
            if not 1 <= int(match.group(3)) <= 65535:
                raise ValueError(f"port {match.group(3)} in {where!r} is outside 1..65535")
            return where
        if not _DEVICE.match(where) or ".." in where.split("/"):
            raise ValueError(f"{where!r} is not a serial device path (/dev/ttyUSB0, COM3) or a URL")
        return where

    @model_validator(mode="after")
    def _line(self) -> ControllerSerial:
        if self.software_parity and (self.bytesize != 7 or self.parity == "none"):
            raise ValueError("software_parity needs bytesize 7 and parity even or odd")
        if self.link_capacity is not None and self.link is None:
            raise ValueError("link_capacity needs link: the name of the device server or uplink it is of")
        return self

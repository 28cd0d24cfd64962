"""Serial DNC (`jobs.controller: {type: serial}`): RS-232 load and drip-feed, and what the machine sends
between jobs, over the pure codec gateway/codecs/dnc/.

One feature package: config.py the line's settings and punch.py `jobs.punch`; port.py (pyserial),
lineio.py (the lines' one I/O thread), transfer.py, fleet.py (drip-feeds sharing a device server) and
transport.py (`SerialTransport`, one owner per line) send; idle.py, desk.py and received.py hear the
idle line (punches, remote requests); transfers.py the transfer log; methods.py the `Commands` drip-feed
methods and line status; control.py the shell's drip-feed commands; lines.py assembles a gateway's
serial machines. Its verb is `cnc-gateway dnc log` (gateway/cli/dnc.py: it reads the gateway file).
"""

from __future__ import annotations

from collections.abc import Sequence

from gateway.transports.base import CorePorts, Deliveries, MachineJobs, TransportSpec
from gateway.transports.dnc.config import ControllerSerial


def assemble(machines: Sequence[MachineJobs], core: CorePorts) -> Deliveries:
    from gateway.transports.dnc.lines import SerialLines

    return SerialLines(machines, core)


SPEC = TransportSpec(
    type="serial",
    settings=ControllerSerial,
    assemble=assemble,
    summary="an RS-232 line (pyserial; direct, RFC 2217 or raw TCP): load or drip-feed, punch, requests",
)

"""The simulator's serial DNC face: a Fanuc-style reader/punch interface (RS-232 through a device server).

    spec = DncSpec(line=LineSettings(baud=9600), mode=Mode.DRIP, buffer_size=256)
    async with DncFace(spec, machine, store, tcp_port=0, rfc2217_port=0, pty=True, speed=10) as face:
        face.socket_url, face.rfc2217_url, face.pty_path    # where pyserial opens it
        face.punch("demo.nc"); face.request("O4711")          # the operator's PUNCH and remote request
        face.stats()                                         # DC1/DC3, after-DC3 counts, starvations ...

`Simulator(dnc=DncOptions(...))` starts it with the rest of the simulator; `DncOptions(device_server=...)`
says what the raw TCP port is (`7bit`, as a device server set 7E2, by default; or `transparent`).
"""

from simulator.dnc.controller import DncController, DncSpec, DncStats, Mode, Stage
from simulator.dnc.face import DncFace, DncOptions
from simulator.dnc.uart import Coupling, DeviceServer, Frame, resample

__all__ = [
    "Coupling",
    "DeviceServer",
    "DncController",
    "DncFace",
    "DncOptions",
    "DncSpec",
    "DncStats",
    "Frame",
    "Mode",
    "Stage",
    "resample",
]

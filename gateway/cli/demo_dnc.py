"""The demo's serial machine: a second simulator with its DNC face, and a drip-feed kept going.

`cnc-gateway demo` runs it beside the laser: a simulator on its own ports whose
controller takes programs over a raw TCP device server (the simulator's DNC face,
socket://127.0.0.1:4001 by default) in drip mode, and the mapping
mappings/laser-dnc.yaml pointed at it. `keep_dripping` submits a generated
contour program to that machine's job queue whenever its queue is empty and the
machine idle, so the demo always shows a drip-feed: progress on OPC UA
(`Jobs/Block`, `Jobs/LeadSeconds`, ...), MQTT (`jobs/<id>`) and `cnc-gateway jobs`.

The device server is the simulator's default kind, a 7-bit one (as an NPort set
7E2 is: its UART does the parity), and the mapping leaves `software_parity` at
its default, as a user would. `punch_once` plays the operator once at start:
the controller punches demo.nc, so that the gateway's store of punched programs
holds one and `cnc-gateway programs received laser-dnc` has something to show.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gateway.config.mapping import MachineMapping
from gateway.errors import RequestError
from gateway.sources.base import settings_of
from gateway.sources.opcua.config import OpcUaDriver
from gateway.transports.dnc.config import ControllerSerial

log = logging.getLogger("gateway.demo")

DRIP_NAME = "drip-demo.nc"
PAUSE = 30.0  # s between the end of one drip-feed and the next: time to try a remote request (README)
PUNCHED = "demo.nc"  # the program the controller punches at start (one of the simulator's samples)
PUNCH_TRIES = 30  # looks, PUNCH_EVERY apart, for a moment the line is free to punch
PUNCH_EVERY = 1.0  # s


def drip_program(turns: int = 12, points: int = 90) -> bytes:
    """A spiral of short moves (a few thousand blocks): far larger than the controller's buffer."""
    lines = [
        "%",
        "O2001 (DNC DRIP DEMO)",
        "(cnc-gateway demo: a spiral of short moves, drip-fed over the serial line)",
        "G21 G90 G17 G94",
        "G0 Z10",
        "G0 X600 Y400",
        "G0 Z1",
        "S1500 M3",
    ]
    for step in range(turns * points):
        angle = 2 * math.pi * step / points
        radius = 20 + 150 * step / (turns * points)
        x, y = 600 + radius * math.cos(angle), 400 + radius * math.sin(angle)
        lines.append(f"G1 X{x:.3f} Y{y:.3f} F6000")
    lines += ["M5", "G0 Z10", "M30", "%", ""]
    return "\n".join(lines).encode("ascii")


def point_at(mapping: MachineMapping, *, opcua_port: int, dnc_port: int) -> MachineMapping:
    """The serial machine's mapping with the demo's ports."""
    driver = settings_of(mapping, OpcUaDriver).model_copy(
        update={"endpoint": f"opc.tcp://127.0.0.1:{opcua_port}"}
    )
    mapping = mapping.model_copy(update={"driver": driver})
    if mapping.jobs is not None and isinstance(mapping.jobs.controller, ControllerSerial):
        controller = mapping.jobs.controller.model_copy(update={"where": f"socket://127.0.0.1:{dnc_port}"})
        mapping = mapping.model_copy(
            update={"jobs": mapping.jobs.model_copy(update={"controller": controller})}
        )
    return mapping


def simulator(args: Any, store: Path) -> Any:
    """The serial machine's simulator: drip mode, a 1 KB receive buffer, the DNC face on `sim_dnc_port`."""
    from gateway.codecs.dnc import LineSettings
    from simulator.dnc import DncOptions, DncSpec, Mode
    from simulator.runner import Simulator

    spec = DncSpec(
        line=LineSettings(baud=9600), mode=Mode.DRIP, buffer_size=1024, high_water=512, low_water=128
    )
    store.mkdir(parents=True, exist_ok=True)
    return Simulator(
        opcua_port=args.sim_dnc_opcua_port,
        ftp_port=args.sim_dnc_ftp_port,
        speed=args.speed,
        store=store,
        dnc=DncOptions(spec, tcp_port=args.sim_dnc_port, rfc2217_port=None),  # the default 7-bit kind
    )


async def punch_once(sim: Any, state_dir: Path, machine: str) -> None:
    """Unless the machine's store of punched programs holds one already, the operator's PUNCH of demo.nc
    as soon as the gateway listens on the line (the simulator refuses while a transfer runs: try again)."""
    from gateway.transports.dnc.received import ReceivedStore

    if await asyncio.to_thread(ReceivedStore(state_dir).list, machine):
        return
    face = sim.dnc
    for _ in range(PUNCH_TRIES):
        await asyncio.sleep(PUNCH_EVERY)
        if not face.controller.connected:
            continue  # the gateway has not opened the line yet
        try:
            face.punch(PUNCHED)
        except RequestError as exc:
            log.debug("demo: no punch yet: %s", exc)
            continue
        face.kick()
        log.info("demo: %s punched by %s's controller (cnc-gateway programs received %s)", PUNCHED, machine,
                 machine)  # fmt: skip
        return
    log.warning("demo: %s's line never was free to punch %s", machine, PUNCHED)


async def keep_dripping(jobs: Any, machine: str, idle: Callable[[], bool]) -> None:
    """Submit the drip program whenever the machine's queue is empty and the machine idle."""
    program = drip_program()
    while True:
        await asyncio.sleep(PAUSE)
        if jobs.machine_busy(machine) or not idle():
            continue
        reply = await jobs.submit_bytes(machine, DRIP_NAME, program, user="demo", origin="demo")
        log.info("demo: drip-feed of %s to %s: %s", DRIP_NAME, machine, reply.message)

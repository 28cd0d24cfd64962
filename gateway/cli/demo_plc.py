"""The demo's PLC-side machines: the laser's chiller over Modbus TCP and the laser's PLC over S7comm.

Both are faces of the in-process simulator (the chiller on 5502, the PLC on 1102 by default; `off` leaves
a machine out), read with the shipped mappings/chiller-sim.yaml and mappings/laser-sim-s7.yaml as a user
would run them, as machines of their own beside laser-sim (a mapping has one driver, and a shop sees
its chiller as a device of its own), with MQTT writes allowed as for laser-sim.
"""

from __future__ import annotations

import argparse
import os
from typing import Any

from pydantic import BaseModel

from gateway.config.mapping import MachineMapping
from gateway.sinks.mqtt.config import MachineMqtt

MAPPINGS = {"modbus": "chiller-sim.yaml", "s7": "laser-sim-s7.yaml"}


def _port_or_off(text: str) -> int | None:
    if text.strip().lower() in ("off", "none", "no"):
        return None
    try:
        port = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a port number (or 'off')") from None
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"port {port} is outside 0..65535")
    return port


def _default(env: str, port: int) -> int | None:
    try:
        return _port_or_off(os.environ.get(env, str(port)))
    except argparse.ArgumentTypeError:
        return port


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--sim-modbus-port", type=_port_or_off, default=_default("CNC_SIM_MODBUS_PORT", 5502),
        help="the simulated chiller's Modbus TCP port (default $CNC_SIM_MODBUS_PORT or 5502; 'off': none)",
    )  # fmt: skip
    p.add_argument(
        "--sim-s7-port", type=_port_or_off, default=_default("CNC_SIM_S7_PORT", 1102),
        help="the simulated PLC's S7 port (default $CNC_SIM_S7_PORT or 1102; 'off': no PLC machine)",
    )  # fmt: skip


def ports(args: argparse.Namespace) -> dict[str, int]:
    """The faces the demo runs: driver type -> port."""
    chosen = {"modbus": args.sim_modbus_port, "s7": args.sim_s7_port}
    return {kind: port for kind, port in chosen.items() if port is not None}


def simulator_ports(args: argparse.Namespace) -> dict[str, Any]:
    """The Simulator's keyword arguments for the faces."""
    return {"modbus_port": args.sim_modbus_port, "s7_port": args.sim_s7_port}


def mapping_names(args: argparse.Namespace) -> list[str]:
    return [MAPPINGS[kind] for kind in ports(args)]


def point(mappings: list[MachineMapping], args: argparse.Namespace) -> list[MachineMapping]:
    """The mappings pointed at the demo's simulator, MQTT writes allowed."""
    out = []
    for mapping, port in zip(mappings, ports(args).values(), strict=True):
        settings = mapping.driver
        assert isinstance(settings, BaseModel)  # the driver's own settings model (modbus, s7)
        driver = settings.model_copy(update={"host": "127.0.0.1", "port": port})
        mqtt = mapping.mqtt or MachineMqtt(writable=True)
        out.append(mapping.model_copy(update={"driver": driver, "mqtt": mqtt}))
    return out


def banner(args: argparse.Namespace, prefix: str | None) -> list[str]:
    lines = []
    chosen = ports(args)
    if "modbus" in chosen:
        port = chosen["modbus"]
        lines.append(f"  chiller (Modbus) modbus://127.0.0.1:{port}/1: OPC UA Objects/Machines/chiller/"
                     "Temperatures/Supply, Setpoint (operators write 10-30 degC)")  # fmt: skip
        lines.append(
            f"  scan it          cnc-gateway modbus scan 127.0.0.1 --port {port} --table input --range 0-15"
        )
        if prefix is not None:
            lines.append(
                f"  chiller on MQTT  {prefix}/chiller/#; mosquitto_pub -t {prefix}/chiller/setpoint/set -m 18"
            )
    if "s7" in chosen:
        port = chosen["s7"]
        lines.append(f"  PLC (S7)         s7://127.0.0.1:{port}/0/1: OPC UA Objects/Machines/laser-plc/"
                     "Laser/Power, PLC/Clock, Requests/Override")  # fmt: skip
        read = f"cnc-gateway s7 read 127.0.0.1 --port {port} DB10.DBD16 'DB10.DBB38:STRING[32]'"
        lines.append(f"  read it          {read}")
        if prefix is not None:
            topic = f"{prefix}/laser-plc/requests/override/set"
            lines.append(f"  PLC on MQTT      {prefix}/laser-plc/#; mosquitto_pub -t {topic} -m 80")
    return lines

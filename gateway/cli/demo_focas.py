"""The demo's FOCAS machine, `fanuc-sim`: the simulator's laser read as a Fanuc over FOCAS2 (port 8193)."""

from __future__ import annotations

import argparse
import os
from collections.abc import Callable

from gateway.config.mapping import MachineMapping
from gateway.sinks.mqtt.config import MachineMqtt
from gateway.sources.focas.config import FocasDriver
from gateway.transports.focas.config import ControllerFocas

DEFAULT_PORT = 8193
MAPPING = "fanuc-sim.yaml"
ENV = "CNC_SIM_FOCAS_PORT"


def add_arguments(p: argparse.ArgumentParser, port_or_off: Callable[[str], int | None]) -> None:
    p.add_argument(
        "--sim-focas-port", type=port_or_off, default=_default(port_or_off),
        help="the simulator's FOCAS2 face, read by the fanuc-sim machine "
        "(default $CNC_SIM_FOCAS_PORT or 8193; 'off': no such machine)",
    )  # fmt: skip


def _default(port_or_off: Callable[[str], int | None]) -> int | None:
    try:
        return port_or_off(os.environ.get(ENV, str(DEFAULT_PORT)))
    except argparse.ArgumentTypeError:
        return DEFAULT_PORT


def point_at(mapping: MachineMapping, port: int) -> MachineMapping:
    """fanuc-sim on the demo's port, its MQTT writes and commands open like the laser's."""
    assert isinstance(mapping.driver, FocasDriver)
    update: dict[str, object] = {
        "driver": mapping.driver.model_copy(update={"host": "127.0.0.1", "port": port})
    }
    if mapping.jobs is not None and isinstance(mapping.jobs.controller, ControllerFocas):
        controller = mapping.jobs.controller.model_copy(update={"host": "127.0.0.1", "port": port})
        update["jobs"] = mapping.jobs.model_copy(update={"controller": controller})
    if mapping.mqtt is None:
        update["mqtt"] = MachineMqtt(writable=True, commands=True)
    return mapping.model_copy(update=update)


def banner(port: int | None, external: bool) -> list[str]:
    if port is None or external:
        return []
    return [
        (
            f"  FOCAS2           focas://127.0.0.1:{port}  (the simulator as a Fanuc; machine fanuc-sim, "
            f"mappings/{MAPPING}; programs to it: FTP inbox folder /fanuc-sim/; docs/focas.md)"
        )
    ]

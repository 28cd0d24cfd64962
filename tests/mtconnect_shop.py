"""A shop of laser cutters for the MTConnect tests and bench: laser-sim's mapping, N times, grown to M items.

Each machine is mappings/laser-sim.yaml (its MTConnect profile included) renamed `laserNN`,
plus filler variables (half SAMPLE TEMPERATURE, half unmapped) until it has `items`
data items in the agent. Nothing here connects: drivers point at a port nobody serves.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import yaml

from gateway.config.gateway import GatewayConfig
from gateway.config.loader import Config
from gateway.config.mapping import MachineMapping
from gateway.sinks.mtconnect.config import AgentConfig

ROOT = Path(__file__).resolve().parent.parent
LASER = yaml.safe_load((ROOT / "mappings" / "laser-sim.yaml").read_text(encoding="utf-8"))
OWN_ITEMS = 3  # availability, asset changed, asset removed (with jobs); + SYSTEM with alarms


def machine(index: int, items: int = 0, *, endpoint: str = "opc.tcp://127.0.0.1:9") -> MachineMapping:
    data: dict[str, Any] = copy.deepcopy(LASER)
    data["machine"] = f"laser{index:02d}"
    data["driver"]["endpoint"] = endpoint
    data.pop("copydata", None)
    data.pop("jobs", None)
    variables = data["variables"]
    base = len(variables) + 2  # + AVAILABILITY + SYSTEM
    for n in range(max(0, items - base)):
        entry: dict[str, Any] = {
            "path": f"Extra/T{n:04d}",
            "source": f"ns=2;s=::Extra:t{n}",
            "type": "Double",
        }
        if n % 2 == 0:
            entry["unit"] = "degC"
            entry["mtconnect"] = {"category": "SAMPLE", "type": "TEMPERATURE", "component": "Systems/Coolant"}
        variables.append(entry)
    return MachineMapping.model_validate(data)


def shop(machines: int = 20, items: int = 500, *, port: int = 0, persist: bool = False,
         buffer_size: int = 131_072, state_dir: Path = Path("state")) -> Config:  # fmt: skip
    agent = AgentConfig(host="127.0.0.1", port=port, persist=persist, buffer_size=buffer_size)
    gateway = GatewayConfig(mtconnect=agent, state_dir=str(state_dir))
    mappings = tuple(machine(i + 1, items) for i in range(machines))
    return Config(gateway, mappings, state_dir.parent if state_dir.is_absolute() else Path.cwd())

"""A gateway on mappings/fanuc-sim.yaml against a simulator whose FOCAS face listens on a free port."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

from gateway.app import Gateway
from gateway.config.gateway import GatewayConfig
from gateway.config.loader import Config, load_mapping
from gateway.config.mapping import MachineMapping
from simulator.runner import Simulator
from tests.waiting import free_port

ROOT = Path(__file__).resolve().parents[3]
MACHINE = "fanuc-sim"


def fanuc_mapping(port: int, **driver: Any) -> MachineMapping:
    mapping = load_mapping(ROOT / "mappings" / "fanuc-sim.yaml", environ={"FANUC_SIM_PORT": str(port)})
    settings = {"reconnect": {"initial": 0.1, "max": 0.5, "factor": 2}, **driver}
    return mapping.model_copy(
        update={"driver": mapping.driver.model_validate({**mapping.driver.model_dump(), **settings})}
    )


def gateway_config(tmp_path: Path, *mappings: MachineMapping, **extra: Any) -> Config:
    gateway = GatewayConfig.model_validate(
        {
            "opcua": {"endpoint": f"opc.tcp://127.0.0.1:{free_port()}/cnc-gateway", "security": ["None"]},
            "state_dir": str(tmp_path / "state"),
            "inbox": {"enabled": False},
            "http": None,
            **extra,
        }
    )
    return Config(gateway, tuple(mappings), tmp_path)


def simulator(tmp_path: Path, port: int = 0, **kwargs: Any) -> Simulator:
    args: dict[str, Any] = {"opcua_port": 0, "ftp_port": 0, "store": tmp_path / "store", **kwargs}
    return Simulator(focas_port=port, **args)


@asynccontextmanager
async def running(config: Config) -> AsyncIterator[Gateway]:
    async with Gateway(config) as gw:
        task = asyncio.create_task(gw.run(), name="gateway")
        try:
            yield gw
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)


def value(gw: Gateway, path: str, machine: str = MACHINE) -> Any:
    sample = gw.tree.find(machine, path).sample
    return sample.value if sample.good else None

"""A gateway with users (viewer, operator, engineer) around the shipped laser-sim mapping and a simulator."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gateway.app import Gateway
from gateway.auth.passwords import hash_password
from gateway.config.gateway import GatewayConfig
from gateway.config.loader import Config, load_mapping
from gateway.config.mapping import MachineMapping
from simulator.runner import Simulator
from tests.opcua_client import Client
from tests.waiting import free_port

ROOT = Path(__file__).resolve().parents[3]
MACHINE = "laser-sim"
# name -> (role, password). Cheap scrypt parameters: these tests log in dozens of times.
USERS = {
    "vera": ("viewer", "vera-secret"),
    "otto": ("operator", "otto-secret"),
    "erik": ("engineer", "erik-secret"),
}


def users_config() -> list[dict[str, str]]:
    return [
        {"name": name, "role": role, "password_hash": hash_password(password, n=2**10)}
        for name, (role, password) in USERS.items()
    ]


def laser_mapping(
    sim_port: int, ftp_port: int, *, jobs: dict[str, Any] | None = None, **update: Any
) -> MachineMapping:
    """mappings/laser-sim.yaml against a simulator on these ports; `jobs` updates its jobs section."""
    mapping = load_mapping(
        ROOT / "mappings" / "laser-sim.yaml",
        environ={"LASER_SIM_ENDPOINT": f"opc.tcp://127.0.0.1:{sim_port}", "LASER_SIM_COPYDATA_PORT": "0"},
    )
    driver = mapping.driver.model_copy(update={"watchdog_interval": 0.5})
    assert mapping.jobs is not None
    controller = mapping.jobs.controller.model_copy(update={"port": ftp_port})
    section = mapping.jobs.model_copy(update={"controller": controller, **(jobs or {})})
    return mapping.model_copy(update={"driver": driver, "jobs": section, **update})


@dataclass
class Rig:
    gateway: Gateway
    sim: Simulator | None
    endpoint: str
    state_dir: Path

    @property
    def machine(self) -> Any:
        return self.gateway.tree.machines[MACHINE]

    def client(self, user: str | None = None, password: str | None = None) -> Client:
        client = Client(self.endpoint, timeout=5)
        if user is not None:
            client.set_user(user)
            client.set_password(password if password is not None else USERS[user][1])
        return client


@asynccontextmanager
async def secure_gateway(
    tmp_path: Path,
    *,
    simulator: bool = True,
    gateway: dict[str, Any] | None = None,
    mapping: dict[str, Any] | None = None,
    opcua: dict[str, Any] | None = None,
    jobs: dict[str, Any] | None = None,
) -> AsyncIterator[Rig]:
    """The gateway (users configured, so access control is on), and the simulator unless told otherwise.
    `opcua` replaces the OPC UA security settings (default: the None endpoint only, no certificate);
    `jobs` updates the machine's jobs section."""
    sim_port, ftp_port, port = free_port(), free_port(), free_port()
    state = tmp_path / "state"
    settings: dict[str, Any] = {
        "opcua": {"endpoint": f"opc.tcp://127.0.0.1:{port}/cnc-gateway", **(opcua or {"profile": "open"})},
        "state_dir": str(state),
        "inbox": {"port": free_port()},
        "users": users_config(),
    }
    settings.update(gateway or {})
    config = Config(
        GatewayConfig.model_validate(settings),
        (laser_mapping(sim_port, ftp_port, jobs=jobs, **(mapping or {})),),
        tmp_path,
    )
    sim = None
    if simulator:
        sim = Simulator(opcua_port=sim_port, ftp_port=ftp_port, speed=20.0, store=tmp_path / "store")
        await sim.__aenter__()
    try:
        async with Gateway(config) as gw:
            task = asyncio.create_task(gw.run(), name="test:gateway")
            try:
                yield Rig(gw, sim, f"opc.tcp://127.0.0.1:{port}/cnc-gateway", state)
            finally:
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)
    finally:
        if sim is not None:
            await sim.__aexit__(None, None, None)

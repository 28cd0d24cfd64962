"""The demo's serial machine as `cnc-gateway demo` sets it up: mappings/laser-dnc.yaml with its defaults,
pointed at a simulator whose raw TCP port is the default 7-bit device server. At start its controller
punches demo.nc once, so that `cnc-gateway programs received laser-dnc` has a program to show at once."""

from __future__ import annotations

import asyncio
import subprocess
import sys
from argparse import Namespace
from pathlib import Path

from gateway.app import Gateway
from gateway.cli.demo import find_mapping
from gateway.cli.demo_dnc import PUNCHED, point_at, punch_once
from gateway.cli.demo_dnc import simulator as dnc_simulator
from gateway.config.gateway import GatewayConfig
from gateway.config.loader import Config, load
from gateway.sinks.opcua.config import OpcUaServerConfig
from gateway.transports.dnc.config import ControllerSerial
from gateway.transports.dnc.received import ReceivedStore
from tests.waiting import free_port, wait_until

BIN = Path(sys.executable).parent


async def test_the_demos_serial_store_holds_one_punched_program_from_the_start(tmp_path: Path) -> None:
    args = Namespace(
        sim_dnc_opcua_port=free_port(), sim_dnc_ftp_port=free_port(), sim_dnc_port=free_port(), speed=4.0
    )
    base = load([find_mapping(None, "laser-dnc.yaml")], environ={})
    mapping = point_at(base.machines[0], opcua_port=args.sim_dnc_opcua_port, dnc_port=args.sim_dnc_port)
    assert mapping.jobs is not None and isinstance(mapping.jobs.controller, ControllerSerial)
    assert mapping.jobs.controller.software_parity is False  # the mapping leaves it at its default (off)
    state = tmp_path / "state"
    gateway = GatewayConfig(
        opcua=OpcUaServerConfig(endpoint=f"opc.tcp://127.0.0.1:{free_port()}/cnc-gateway"),
        state_dir=str(state),
    )
    async with dnc_simulator(args, tmp_path / "simulator-dnc-store") as sim:
        assert sim.dnc.device_server.value == "7bit"  # the simulator's default kind
        async with Gateway(Config(gateway, (mapping,), tmp_path)) as gw:
            task = asyncio.create_task(gw.run(("demo:punch", lambda: punch_once(sim, state, "laser-dnc"))))
            try:
                await wait_until(
                    lambda: ReceivedStore(state).list("laser-dnc"), timeout=60, message="the punched program"
                )
            finally:
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)
    [program] = ReceivedStore(state).list("laser-dnc")
    assert program.number == 1001 and program.verdict == "accepted"  # demo.nc: O1001 (DEMO LASER JOB)
    assert sim.dnc.stats()["tx_chars"] > 0 and sim.programs.exists(PUNCHED)
    listed = await asyncio.to_thread(
        subprocess.run,
        [str(BIN / "cnc-gateway"), "programs", "received", "laser-dnc", "--state-dir", str(state)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert listed.returncode == 0, listed.stderr
    assert program.file in listed.stdout

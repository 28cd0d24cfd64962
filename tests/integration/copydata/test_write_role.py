"""COPYDATA has no login (issue 23, item 4): a target that accepts writes runs only with the role the gateway
file names for them (access.copydata_role), never with an implied one.

Before the fix, the shipped laser-sim mapping's target (accept_writes: true) under a gateway file without
users acted as admin: one 14-byte frame from anyone who reached the port was audited as
`anonymous@copydata/admin laser-sim/Feed/Override 100 -> 150 ok`. Now the same files are refused at load time,
naming the mapping file, the line and the key, and nothing listens; with `copydata_role: operator` the
same frame is a write audited with that role.
"""

from __future__ import annotations

import asyncio
import socket
import struct
import subprocess
import sys
from pathlib import Path

import pytest

from gateway.app import Gateway
from gateway.config.loader import load
from gateway.errors import ConfigError
from gateway.model.audit import AuditEntry
from simulator.runner import Simulator
from tests.waiting import free_port, wait_until

ROOT = Path(__file__).resolve().parents[3]
BIN = Path(sys.executable).parent
OVERRIDE_ID = 6  # Feed/Override (UInt16, readwrite 0..150, role operator) in mappings/laser-sim.yaml
FRAME = struct.pack("<IIHHH", 1, 6, OVERRIDE_ID, 2, 150)  # dwData=1, cbData=6: Feed/Override = 150


def write_files(tmp_path: Path, access: str = "") -> tuple[Path, Path]:
    """The shipped laser-sim mapping with its target's accept_writes on, and a gateway file without users."""
    text = (ROOT / "mappings" / "laser-sim.yaml").read_text(encoding="utf-8")
    assert "      accept_writes: false" in text
    mapping = tmp_path / "laser-sim.yaml"
    mapping.write_text(
        text.replace("      accept_writes: false", "      accept_writes: true"), encoding="utf-8"
    )
    gateway = tmp_path / "gateway.yaml"
    gateway.write_text(
        "opcua: {endpoint: 'opc.tcp://127.0.0.1:${GW_OPCUA_PORT}/cnc-gateway'}\n"
        "state_dir: state\n"
        "inbox: {enabled: false}\n"
        "machines: [laser-sim.yaml]\n" + access,
        encoding="utf-8",
    )
    return gateway, mapping


def accept_writes_line(mapping: Path) -> int:
    lines = mapping.read_text(encoding="utf-8").splitlines()
    return next(n for n, line in enumerate(lines, 1) if line.strip().startswith("accept_writes: true"))


def listening(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.5)
        return s.connect_ex(("127.0.0.1", port)) == 0


def test_a_target_that_accepts_writes_without_a_role_is_refused_at_load_time(tmp_path: Path) -> None:
    gateway, mapping = write_files(tmp_path)
    copydata_port = free_port()
    env = {"GW_OPCUA_PORT": str(free_port()), "LASER_SIM_COPYDATA_PORT": str(copydata_port)}
    with pytest.raises(ConfigError) as info:
        load([gateway], environ=env)
    [issue] = info.value.issues
    assert (issue.file, issue.line, issue.key) == (
        str(mapping),
        accept_writes_line(mapping),
        "copydata.targets[0].accept_writes",
    )
    assert "access.copydata_role in the gateway file" in issue.message and str(gateway) in issue.message

    # `cnc-gateway run` says the same and starts nothing: no COPYDATA port to send the frame to.
    proc = subprocess.run(
        [str(BIN / "cnc-gateway"), "run", str(gateway)],
        capture_output=True, text=True, timeout=60, check=False, env={"PATH": str(BIN), **env},
    )  # fmt: skip
    assert proc.returncode == 2, proc.stderr
    assert f"{mapping}:{accept_writes_line(mapping)}: copydata.targets[0].accept_writes" in proc.stderr
    assert "nothing was started" in proc.stderr
    with pytest.raises(ConnectionRefusedError), socket.create_connection(("127.0.0.1", copydata_port), 2):
        pass


def test_a_mapping_run_on_its_own_cannot_accept_copydata_writes(tmp_path: Path) -> None:
    _, mapping = write_files(tmp_path)
    with pytest.raises(ConfigError, match="in a gateway file \\(this mapping runs on its own"):
        load([mapping], environ={})


async def test_with_a_role_the_frame_writes_and_is_audited_with_that_role(tmp_path: Path) -> None:
    gateway_file, _ = write_files(tmp_path, "access: {copydata_role: operator}\n")
    sim_port, copydata_port = free_port(), free_port()
    env = {
        "GW_OPCUA_PORT": str(free_port()),
        "LASER_SIM_ENDPOINT": f"opc.tcp://127.0.0.1:{sim_port}",
        "LASER_SIM_COPYDATA_PORT": str(copydata_port),
    }
    config = load([gateway_file], environ=env)
    mapping = config.machines[0].model_copy(update={"jobs": None})
    config = type(config)(config.gateway, (mapping,), config.base_dir, config.files)
    audited: list[AuditEntry] = []
    store = tmp_path / "store"
    store.mkdir()
    async with (
        Simulator(opcua_port=sim_port, ftp_port=free_port(), speed=20.0, store=store) as sim,
        Gateway(config) as gw,
    ):
        gw.tree.audit_sinks.append(audited.append)
        run = asyncio.create_task(gw.run(), name="gateway")
        try:
            machine = gw.tree.machines["laser-sim"]
            await wait_until(lambda: machine.nodes["Feed/Override"].sample.good, timeout=20,
                             message="the gateway connected to the simulator")  # fmt: skip
            await wait_until(lambda: listening(copydata_port), message="the COPYDATA target listening")
            assert sim.machine.override != 150
            reader, writer = await asyncio.open_connection("127.0.0.1", copydata_port)
            try:
                writer.write(FRAME)
                await writer.drain()
                await wait_until(lambda: sim.machine.override == 150, message="the write at the simulator")
            finally:
                writer.close()
                del reader
            entry = await wait_until(lambda: [e for e in audited if e.target == "Feed/Override"],
                                     message="the audit entry")  # fmt: skip
            [write] = entry
            assert (write.origin, write.user, write.role, write.new, write.status) == (
                "copydata", None, "operator", "150", "Good",
            )  # fmt: skip
        finally:
            run.cancel()
            await asyncio.gather(run, return_exceptions=True)

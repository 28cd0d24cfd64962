"""`cnc-gateway fleet FLEET.yaml`: two shard processes of one gateway file over a simulator fleet.

Each shard serves its half of the machines (static shards, `shard: ${CNC_SHARD}`), seen on its own
/metrics; a shard killed with SIGKILL is started again by the supervisor and serves its machines again;
SIGTERM to the supervisor stops every shard cleanly, and no process is left.
"""

from __future__ import annotations

import asyncio
import os
import re
import signal
import sys
import urllib.request
from pathlib import Path

from simulator.fleet import SimulatorFleet
from tests.waiting import free_port, wait_until


def connected(port: int) -> set[str]:
    """The machines a shard says it is connected to, from its /metrics."""
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=2) as answer:
            text = answer.read().decode()
    except OSError:
        return set()
    return set(re.findall(r'cnc_gateway_machine_connected\{machine="([^"]+)"\} 1\.0', text))


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


async def test_shards_serve_their_machines_come_back_after_a_kill_and_stop_together(tmp_path: Path) -> None:
    http, opcua, inbox = free_port(), free_port(), free_port()
    for port in (http + 1, opcua + 1, inbox + 1):  # each shard's port is the base + K - 1
        assert port != 0
    async with SimulatorFleet(4, store_root=tmp_path / "stores", tick=0.1) as sims:
        names = [p.name for p in sims.write_mappings(tmp_path)]
        (tmp_path / "gateway.yaml").write_text(
            f"machines: {names}\n"
            "shard: ${CNC_SHARD}\n"
            "state_dir: ${CNC_STATE_DIR}\n"
            "opcua: {endpoint: 'opc.tcp://127.0.0.1:${OPCUA_PORT}/cnc-gateway', security: [None]}\n"
            "http: {host: 127.0.0.1, port: '${HTTP_PORT}'}\n"
            "inbox: {host: 127.0.0.1, port: '${INBOX_PORT}'}\n"
        )
        (tmp_path / "fleet.yaml").write_text(
            "gateway: gateway.yaml\nshards: 2\n"
            f"ports: {{HTTP_PORT: {http}, OPCUA_PORT: {opcua}, INBOX_PORT: {inbox}}}\n"
            "state_dir: state\nrestart: {initial: 0.2, max: 1}\n"
        )
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "gateway.cli.main", "fleet", str(tmp_path / "fleet.yaml"),
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
        )  # fmt: skip
        out: list[str] = []
        err: list[str] = []

        async def read(stream: asyncio.StreamReader | None, into: list[str]) -> None:
            assert stream is not None
            while line := await stream.readline():
                into.append(line.decode())

        readers = [asyncio.create_task(read(proc.stdout, out)), asyncio.create_task(read(proc.stderr, err))]
        try:
            await wait_until(lambda: connected(http) == {"laser-001", "laser-003"}, timeout=60,
                             message="shard 1/2 serving laser-001 and laser-003")  # fmt: skip
            await wait_until(lambda: connected(http + 1) == {"laser-002", "laser-004"}, timeout=60,
                             message="shard 2/2 serving laser-002 and laser-004")  # fmt: skip
            await wait_until(lambda: any("every shard started" in line for line in out), timeout=10,
                             message="the status table")  # fmt: skip
            table = "".join(out)
            pids = {int(k): int(p) for k, p in re.findall(r"shard (\d)/2\s+pid (\d+)", table)}
            assert set(pids) == {1, 2}
            os.kill(pids[2], signal.SIGKILL)
            await wait_until(lambda: any("shard 2/2 ended (killed by SIGKILL)" in line for line in err),
                             timeout=10, message="the supervisor to see the kill")  # fmt: skip
            await wait_until(lambda: any("shard 2/2 started" in line for line in err[-20:]) and
                             connected(http + 1) == {"laser-002", "laser-004"}, timeout=60,
                             message="shard 2/2 started again and serving")  # fmt: skip
            assert connected(http) == {"laser-001", "laser-003"}  # the other shard went on
            restarted = [int(p) for p in re.findall(r"shard 2/2 started \(pid (\d+)\)", "".join(err))][-1]
            proc.send_signal(signal.SIGTERM)
            assert await asyncio.wait_for(proc.wait(), 30) == 0
        finally:
            if proc.returncode is None:
                proc.kill()
                await proc.wait()
            await asyncio.gather(*readers)
    log = "".join(err)
    assert "Traceback" not in log, log[-3000:]
    assert not alive(pids[1]) and not alive(restarted)
    assert "fleet: stopped" in "".join(out)


async def test_check_shows_each_shards_machines_and_refuses_a_bad_fleet_file(tmp_path: Path) -> None:
    names = []
    for i in (1, 2, 3):
        (tmp_path / f"m{i}.yaml").write_text(
            f"machine: m{i}\ndriver: {{endpoint: 'opc.tcp://127.0.0.1:4841'}}\n"
            "variables: [{path: A/B, source: 'ns=2;s=x', type: Double}]\n"
        )
        names.append(f"m{i}.yaml")
    (tmp_path / "gateway.yaml").write_text(
        f"machines: {names}\nshard: ${{CNC_SHARD}}\nstate_dir: ${{CNC_STATE_DIR}}\n"
    )
    (tmp_path / "fleet.yaml").write_text("gateway: gateway.yaml\nshards: 2\n")
    cli = [sys.executable, "-m", "gateway.cli.main", "fleet", "--check"]
    good = await asyncio.create_subprocess_exec(
        *cli, str(tmp_path / "fleet.yaml"), stdout=asyncio.subprocess.PIPE
    )
    text = (await good.communicate())[0].decode()
    assert good.returncode == 0
    assert "shard 1/2: 2 machine(s): m1, m3" in text and "shard 2/2: 1 machine(s): m2" in text
    (tmp_path / "bad.yaml").write_text("gateway: gateway.yaml\nshards: 2\nports: {HTTP_PORT: 99999}\n")
    bad = await asyncio.create_subprocess_exec(
        *cli, str(tmp_path / "bad.yaml"), stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE
    )
    out, err = await bad.communicate()
    assert bad.returncode == 2
    assert re.search(r"bad\.yaml:3.*ports.*99999 is not a port", (out + err).decode()), (out + err).decode()


def running(pid: int) -> bool:
    """Alive and not a zombie (an orphan's zombie stays until whatever adopted it reaps it)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


async def test_shards_stop_when_their_supervisor_is_killed(tmp_path: Path) -> None:
    """SIGKILL leaves the supervisor no chance to stop its shards: they notice and stop on their own, so
    that a supervisor started again does not find the old shards holding the ports and the machines."""
    http, opcua, inbox = free_port(), free_port(), free_port()
    async with SimulatorFleet(2, store_root=tmp_path / "stores", tick=0.1) as sims:
        names = [p.name for p in sims.write_mappings(tmp_path)]
        (tmp_path / "gateway.yaml").write_text(
            f"machines: {names}\n"
            "shard: ${CNC_SHARD}\n"
            "state_dir: ${CNC_STATE_DIR}\n"
            "opcua: {endpoint: 'opc.tcp://127.0.0.1:${OPCUA_PORT}/cnc-gateway', security: [None]}\n"
            "http: {host: 127.0.0.1, port: '${HTTP_PORT}'}\n"
            "inbox: {host: 127.0.0.1, port: '${INBOX_PORT}'}\n"
        )
        (tmp_path / "fleet.yaml").write_text(
            "gateway: gateway.yaml\nshards: 2\n"
            f"ports: {{HTTP_PORT: {http}, OPCUA_PORT: {opcua}, INBOX_PORT: {inbox}}}\n"
            "state_dir: state\n"
        )
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "gateway.cli.main", "fleet", str(tmp_path / "fleet.yaml"),
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
        )  # fmt: skip
        out: list[str] = []
        err: list[str] = []

        async def read(stream: asyncio.StreamReader | None, into: list[str]) -> None:
            assert stream is not None
            while line := await stream.readline():
                into.append(line.decode())

        readers = [asyncio.create_task(read(proc.stdout, out)), asyncio.create_task(read(proc.stderr, err))]
        pids: dict[int, int] = {}
        try:
            await wait_until(lambda: any("every shard started" in line for line in out), timeout=60,
                             message="every shard up")  # fmt: skip
            pids = {int(k): int(p) for k, p in re.findall(r"shard (\d)/2\s+pid (\d+)", "".join(out))}
            assert set(pids) == {1, 2}
            proc.kill()
            await proc.wait()
            await wait_until(lambda: not any(running(p) for p in pids.values()), timeout=30,
                             message="both shards to stop after their supervisor was killed")  # fmt: skip
            # They stopped cleanly, each saying why: the pipes close once both have ended.
            await asyncio.wait_for(asyncio.gather(*readers), timeout=10)
        finally:
            for pid in pids.values():
                if running(pid):
                    os.kill(pid, signal.SIGKILL)
            if proc.returncode is None:
                proc.kill()
                await proc.wait()
            for reader in readers:
                reader.cancel()
            await asyncio.gather(*readers, return_exceptions=True)
    log = "".join(err)
    assert log.count(f"supervisor (pid {proc.pid}) is gone: stopping") == 2, log[-3000:]
    assert "Traceback" not in log, log[-3000:]

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
from tests.fleet_rig import Fleet, write_fleet
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
    async with SimulatorFleet(4, store_root=tmp_path / "stores", tick=0.1) as sims:
        names = [p.name for p in sims.write_mappings(tmp_path)]
        ports = {"HTTP_PORT": http, "OPCUA_PORT": opcua, "INBOX_PORT": inbox}
        async with Fleet(write_fleet(tmp_path, names, ports)) as fleet:
            await wait_until(lambda: connected(http) == {"laser-001", "laser-003"}, timeout=60,
                             message="shard 1/2 serving laser-001 and laser-003")  # fmt: skip
            await wait_until(lambda: connected(http + 1) == {"laser-002", "laser-004"}, timeout=60,
                             message="shard 2/2 serving laser-002 and laser-004")  # fmt: skip
            await wait_until(
                lambda: fleet.said("every shard started"), timeout=10, message="the status table"
            )
            pids = fleet.pids()
            assert set(pids) == {1, 2}
            os.kill(pids[2], signal.SIGKILL)
            await wait_until(lambda: fleet.said("shard 2/2 ended (killed by SIGKILL)"),
                             timeout=10, message="the supervisor to see the kill")  # fmt: skip
            await wait_until(lambda: len(fleet.starts(2)) == 2 and
                             connected(http + 1) == {"laser-002", "laser-004"}, timeout=60,
                             message="shard 2/2 started again and serving")  # fmt: skip
            assert connected(http) == {"laser-001", "laser-003"}  # the other shard went on
            restarted = fleet.starts(2)[-1]
            fleet.proc.send_signal(signal.SIGTERM)
            assert await asyncio.wait_for(fleet.proc.wait(), 30) == 0
    log = "".join(fleet.err)
    assert "Traceback" not in log, log[-3000:]
    assert not alive(pids[1]) and not alive(restarted)
    assert "fleet: stopped" in "".join(fleet.out)


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
    ports = {"HTTP_PORT": free_port(), "OPCUA_PORT": free_port(), "INBOX_PORT": free_port()}
    pids: dict[int, int] = {}
    async with SimulatorFleet(2, store_root=tmp_path / "stores", tick=0.1) as sims:
        names = [p.name for p in sims.write_mappings(tmp_path)]
        async with Fleet(write_fleet(tmp_path, names, ports, restart=None)) as fleet:
            try:
                await wait_until(
                    lambda: fleet.said("every shard started"), timeout=60, message="every shard up"
                )
                pids = fleet.pids()
                assert set(pids) == {1, 2}
                fleet.proc.kill()
                await fleet.proc.wait()
                await wait_until(lambda: not any(running(p) for p in pids.values()), timeout=30,
                                 message="both shards to stop after their supervisor was killed")  # fmt: skip
            finally:
                for pid in pids.values():
                    if running(pid):
                        os.kill(pid, signal.SIGKILL)
    log = "".join(fleet.err)
    assert log.count(f"supervisor (pid {fleet.proc.pid}) is gone: stopping") == 2, log[-3000:]
    assert "Traceback" not in log, log[-3000:]

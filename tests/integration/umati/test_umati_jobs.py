"""ActiveProgram/JobIdentifier follows the gateway's job queue: a program dropped into the FTP inbox,
delivered and auto-started, is the JobIdentifier of the laser's ActiveProgram (the same sample as the
gateway's Jobs/LastDelivered). Uses the demo flow's rig (tests/integration/jobs/test_demo_flow.py)."""

from __future__ import annotations

import asyncio
import shutil
import subprocess
from pathlib import Path

import pytest

from gateway.cli.demo import DEMO_INBOX_PASSWORD, DEMO_INBOX_USER
from tests.integration.jobs.test_demo_flow import PART, broker, demo
from tests.opcua_client import Client
from tests.waiting import wait_until

__all__ = ["broker", "demo"]  # the fixtures this module borrows


@pytest.mark.skipif(shutil.which("curl") is None, reason="curl is not installed")
async def test_the_job_delivered_is_the_active_programs_job_identifier(demo, tmp_path: Path) -> None:
    gw, _sim, args = demo
    machine = gw.tree.machines["laser-sim"]
    await wait_until(lambda: machine.status.is_connected, timeout=20, message="the gateway connected")
    part = tmp_path / "part.nc"
    part.write_bytes(PART)
    url = f"ftp://{DEMO_INBOX_USER}:{DEMO_INBOX_PASSWORD}@127.0.0.1:{args.inbox_port}/laser-sim/"
    proc = await asyncio.create_subprocess_exec(
        "curl", "-sS", "--max-time", "30", "-T", str(part), url, stderr=subprocess.PIPE
    )
    _, err = await proc.communicate()
    assert proc.returncode == 0, err.decode()
    async with Client(gw.sink("opcua").endpoint) as client:
        umati = client.get_node("ns=2;s=umati:laser-sim/Production/ActiveProgram/JobIdentifier")
        own = client.get_node("ns=2;s=laser-sim/Jobs/LastDelivered")
        await wait_until(umati.read_value, timeout=20, message="JobIdentifier")
        at_umati, at_own = await umati.read_data_value(), await own.read_data_value()
        assert at_umati.Value.Value == at_own.Value.Value == "J000001 part.nc"
        assert at_umati.SourceTimestamp == at_own.SourceTimestamp

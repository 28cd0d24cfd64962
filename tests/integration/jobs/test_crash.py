"""The gateway killed mid-delivery (SIGKILL, as a power cut or the OOM killer would) and restarted:
the job is delivered exactly once, and not lost."""

from __future__ import annotations

import asyncio
import hashlib
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

from gateway.jobs.queue.store import JobQueue, JobState
from gateway.jobs.spool import queue_path
from tests.integration.jobs.conftest import PASSWORD, PASSWORD_HASH, USER, Store, in_thread, mapping_text
from tests.waiting import free_port, wait_until

S = JobState
RATE = 1_000_000  # bytes/s to the controller: slow enough to be caught mid-upload


def big_program(size: int) -> bytes:
    pad = "(" + "sheet 4711 nest of 37 parts, 3 mm mild steel " * 3 + ")"
    lines = ["%", "O4711 (SHEET)", "G21 G90"]
    total = 0
    i = 0
    while total < size:
        line = f"N{i} G1 X{i % 1000}.5 Y{(i * 3) % 1000}.5 F6000 {pad}"
        lines.append(line)
        total += len(line) + 1
        i += 1
    return ("\n".join([*lines, "M30", "%"]) + "\n").encode()


def port_open(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.2)
        return s.connect_ex(("127.0.0.1", port)) == 0


async def start_gateway(gateway_file: Path, log: Path) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [str(Path(sys.executable).with_name("cnc-gateway")), "run", str(gateway_file)],
        stdout=log.open("ab"),
        stderr=subprocess.STDOUT,
        cwd=gateway_file.parent,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )


async def test_killed_mid_delivery_and_restarted_delivers_exactly_once(
    store: Store, tmp_path: Path, renames
) -> None:
    inbox_port = free_port()
    mapping = mapping_text("laser", store.port, opcua_port=free_port()).replace(
        "timeout: 5}", f"timeout: 5, rate_limit: {RATE}}}"
    )
    (tmp_path / "laser.yaml").write_text(mapping)
    gateway_file = tmp_path / "gateway.yaml"
    gateway_file.write_text(
        f"opcua: {{endpoint: 'opc.tcp://127.0.0.1:{free_port()}/cnc-gateway'}}\n"
        "state_dir: state\nmachines: [laser.yaml]\nlog_level: info\n"
        f"inbox:\n  host: 127.0.0.1\n  port: {inbox_port}\n  reply_within: 30\n"
        f"  accounts: [{{user: {USER}, password_hash: '{PASSWORD_HASH}'}}]\n"
    )
    log = tmp_path / "gateway.log"
    data = big_program(2_000_000)
    proc = await start_gateway(gateway_file, log)
    try:
        await wait_until(lambda: port_open(inbox_port), timeout=30, message="the inbox to listen")

        def upload() -> str:
            import ftplib
            import io

            ftp = ftplib.FTP()
            ftp.connect("127.0.0.1", inbox_port, timeout=30)
            ftp.login(USER, PASSWORD)
            reply = ftp.storbinary("STOR /laser/sheet.nc", io.BytesIO(data))
            ftp.quit()
            return reply

        assert (await in_thread(upload)).startswith("226 J000001 queued")
        queue = JobQueue(queue_path(tmp_path / "state")).open()
        temp = store.folder() / "sheet.nc.tmp"
        await wait_until(
            lambda: queue.get(1).state is S.SENDING and temp.exists() and 0 < temp.stat().st_size < len(data),
            timeout=30,
            message="the upload to be under way",
        )
        proc.send_signal(signal.SIGKILL)
        await asyncio.to_thread(proc.wait, 30)
        assert queue.get(1).state is S.SENDING  # exactly where the kill left it
        assert "sheet.nc" not in store.files()

        proc = await start_gateway(gateway_file, log)
        job = await wait_until(
            lambda: (j := queue.get(1)).state is S.DELIVERED and j,
            timeout=60,
            message="delivery after the restart",
        )
        queue.close()
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                await asyncio.to_thread(proc.wait, 15)
            except subprocess.TimeoutExpired:
                proc.kill()
    delivered = store.folder() / "sheet.nc"
    assert hashlib.sha256(delivered.read_bytes()).hexdigest() == hashlib.sha256(data).hexdigest()
    assert renames.targets == ["sheet.nc"], log.read_text()[-3000:]  # one complete delivery, no second one
    assert not temp.exists()
    assert job.attempts == 2
    with JobQueue(queue_path(tmp_path / "state")) as q:
        reasons = [t.reason for t in q.history(1)]
        assert q.count() == 1
    assert "interrupted by a restart; sending again" in reasons

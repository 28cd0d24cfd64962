"""Uploads to the gateway's inbox with real clients, through validation and the queue, to a real FTP store."""

from __future__ import annotations

import asyncio
import ftplib
import hashlib
import io
import shutil
import subprocess
from pathlib import Path

import aioftp
import pytest

from gateway.jobs.queue.store import JobState
from gateway.model.events import Event
from tests.integration.jobs.conftest import (
    GOOD,
    PASSWORD,
    PASSWORD_HASH,
    USER,
    Store,
    in_thread,
    mapping_text,
    program,
)
from tests.waiting import wait_until

S = JobState


async def test_a_plain_stor_is_validated_queued_and_delivered(store: Store, harness, renames) -> None:
    async with harness([mapping_text("laser", store.port)]) as h:
        events = h.tree.events.subscribe("test")
        reply = await h.stor("laser", "part.nc", GOOD)
        assert reply.startswith("226 J000001 queued for laser")
        job = await h.wait_state(1, S.DELIVERED)
        assert job.filename == "part.nc" and job.user == USER and job.attempts == 1
        assert job.sha256 == hashlib.sha256(GOOD).hexdigest()
        assert job.estimate["extents"]["max_x"] == 50.0 and job.program_name == "O1001"
        assert store.files() == {
            "part.nc": GOOD,
            "demo.nc": store.files()["demo.nc"],
            "soft-limit.nc": store.files()["soft-limit.nc"],
        }
        assert renames.targets == ["part.nc"]  # uploaded as part.nc.tmp, renamed once
        await wait_until(
            lambda: h.value("laser", "Jobs/LastDelivered") == "J000001 part.nc", message="LastDelivered"
        )
        assert h.value("laser", "Jobs/QueueLength") == 0
        seen: list[Event] = []

        def delivered_event() -> bool:
            seen.extend(events.take())
            return any(e.channel == "jobs/events" and e.payload["state"] == "DELIVERED" for e in seen)

        await wait_until(delivered_event, message="a DELIVERED event")
        states = [e.payload["state"] for e in seen if e.channel == "jobs/events"]
        assert states == ["RECEIVED", "VALIDATED", "QUEUED", "SENDING", "DELIVERED"]
        records = [e for e in seen if e.channel == "jobs/J000001"]
        assert records and all(e.retain for e in records) and records[-1].payload["state"] == "DELIVERED"
        assert records[-1].payload["progress"] == 100.0
        assert list((h.state / "inbox" / "laser").iterdir()) == [h.state / "inbox" / "laser" / "tmp"]


async def test_temporary_name_then_rename_with_aioftp(store: Store, harness) -> None:
    async with harness([mapping_text("laser", store.port)]) as h:
        async with aioftp.Client.context("127.0.0.1", h.port, USER, PASSWORD) as client:
            async with client.upload_stream("/laser/sheet-7.nc.part") as stream:
                await stream.write(GOOD[:20])
                await stream.write(GOOD[20:])
            assert h.jobs() == []  # a temporary name is not a job yet
            names = [p.name for p, _ in await client.list("/laser")]
            assert "sheet-7.nc.part" in names
            await client.rename("/laser/sheet-7.nc.part", "/laser/sheet-7.nc")
        job = await h.wait_state(1, S.DELIVERED)
        assert job.filename == "sheet-7.nc"
        assert store.files()["sheet-7.nc"] == GOOD


async def test_the_tmp_folder_then_rename_with_ftplib(store: Store, harness) -> None:
    async with harness([mapping_text("laser", store.port)]) as h:

        def run() -> str:
            ftp = h.ftp()
            ftp.mkd("/laser/tmp")  # exists already: still fine, as clients expect
            ftp.cwd("/laser/tmp")
            ftp.storbinary("STOR part.nc", io.BytesIO(GOOD))
            assert ftp.size("part.nc") == len(GOOD)
            assert len(ftp.sendcmd("MDTM part.nc").split()[1]) == 14
            ftp.rename("part.nc", "/laser/part.nc")
            ftp.quit()
            return "ok"

        assert await in_thread(run) == "ok"
        await h.wait_state(1, S.DELIVERED)
        assert store.files()["part.nc"] == GOOD


@pytest.mark.skipif(shutil.which("curl") is None, reason="curl is not installed")
async def test_curl_upload_as_nesting_software_does(store: Store, harness, tmp_path: Path) -> None:
    source = tmp_path / "part.nc"
    source.write_bytes(GOOD)
    async with harness([mapping_text("laser", store.port)]) as h:
        proc = await asyncio.create_subprocess_exec(
            "curl",
            "-sS",
            "--max-time",
            "30",
            "-T",
            str(source),
            f"ftp://{USER}:{PASSWORD}@127.0.0.1:{h.port}/laser/",
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        out, err = await proc.communicate()
        assert proc.returncode == 0, err.decode()
        await h.wait_state(1, S.DELIVERED)
        assert store.files()["part.nc"] == GOOD
        # curl also lists and reads sizes the way other clients do
        proc = await asyncio.create_subprocess_exec(
            "curl",
            "-sS",
            "--max-time",
            "30",
            "--list-only",
            f"ftp://{USER}:{PASSWORD}@127.0.0.1:{h.port}/",
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        out, err = await proc.communicate()
        assert proc.returncode == 0, err.decode()
        assert out.decode().split() == ["laser"]


async def test_a_20_mb_program(store: Store, harness) -> None:
    pad = "(" + "nesting software label and sheet data " * 5 + ")"
    lines = ["%", "O7000 (BIG SHEET)", "G21 G90"]
    size = 0
    i = 0
    while size < 20 * 1024 * 1024:
        line = f"N{i} G1 X{i % 1000}.5 Y{(i * 7) % 1000}.25 F6000 {pad}"
        lines.append(line)
        size += len(line) + 1
        i += 1
    data = ("\n".join([*lines, "M30", "%"]) + "\n").encode()
    async with harness([mapping_text("laser", store.port)], reply_within=60) as h:
        async with (
            aioftp.Client.context("127.0.0.1", h.port, USER, PASSWORD) as client,
            client.upload_stream("/laser/big.nc") as stream,
        ):
            for start in range(0, len(data), 1024 * 1024):
                await stream.write(data[start : start + 1024 * 1024])
        job = await h.wait_state(1, S.DELIVERED, timeout=90)
        assert job.size == len(data) > 20 * 1024 * 1024
        delivered = store.folder() / "big.nc"
        assert hashlib.sha256(delivered.read_bytes()).hexdigest() == hashlib.sha256(data).hexdigest()


async def test_concurrent_uploads_to_two_machines(store: Store, harness) -> None:
    mappings = [mapping_text("laser", store.port), mapping_text("plasma", store.port, folder="/DATA/Other")]
    async with harness(mappings) as h:
        uploads = [
            h.stor(m, f"{m}-{n}.nc", program(f"{m} {n}", lines=200))
            for m in ("laser", "plasma")
            for n in range(3)
        ]
        replies = await asyncio.gather(*uploads)
        assert all(r.startswith("226 J") for r in replies), replies
        await wait_until(
            lambda: all(j.state is S.DELIVERED for j in h.jobs()) and len(h.jobs()) == 6,
            timeout=30,
            message="six deliveries",
        )
        assert sorted(n for n in store.files() if n.startswith("laser")) == [
            "laser-0.nc",
            "laser-1.nc",
            "laser-2.nc",
        ]
        assert sorted(store.files("Other")) == ["plasma-0.nc", "plasma-1.nc", "plasma-2.nc"]
        for job in h.jobs():
            folder = "Programs" if job.machine == "laser" else "Other"
            assert store.files(folder)[job.filename] == program(
                job.filename[:-3].replace("-", " "), lines=200
            )


async def test_a_login_sees_only_its_machines(store: Store, harness) -> None:
    mappings = [mapping_text("laser", store.port), mapping_text("plasma", store.port, folder="/DATA/Other")]
    accounts = [{"user": USER, "password_hash": PASSWORD_HASH, "machines": ["plasma"]}]
    async with harness(mappings, accounts=accounts) as h:

        def run() -> tuple[list[str], str, str]:
            ftp = h.ftp()
            names = ftp.nlst("/")
            try:
                ftp.cwd("/laser")
                cwd = "allowed"
            except ftplib.error_perm as exc:
                cwd = str(exc)
            try:
                ftp.storbinary("STOR /laser/x.nc", io.BytesIO(GOOD))
                stor = "stored"
            except ftplib.error_perm as exc:
                stor = str(exc)
            ftp.quit()
            return names, cwd, stor

        names, cwd, stor = await in_thread(run)
        assert names == ["plasma"]
        assert cwd.startswith("550") and "no such machine folder" in cwd
        assert stor.startswith("550")
        assert h.jobs() == []


async def test_commands_real_clients_send(store: Store, harness) -> None:
    async with harness([mapping_text("laser", store.port)]) as h:

        def run() -> dict[str, str]:
            ftp = h.ftp()
            out = {
                "feat": ftp.sendcmd("FEAT"),
                "noop": ftp.sendcmd("NOOP"),
                "opts": ftp.sendcmd("OPTS UTF8 ON"),
                "type": ftp.sendcmd("TYPE I"),
                "mode": ftp.sendcmd("MODE S"),
                "stru": ftp.sendcmd("STRU F"),
                "allo": ftp.sendcmd("ALLO 1000"),
                "pwd": ftp.pwd(),
                "syst": ftp.sendcmd("SYST"),
            }
            ftp.cwd("laser")
            out["pwd2"] = ftp.pwd()
            ftp.storbinary("STOR keep.nc.part", io.BytesIO(b"partial"))
            out["size"] = str(ftp.size("keep.nc.part"))
            out["mlsd"] = ";".join(name for name, _ in ftp.mlsd())
            lines: list[str] = []
            ftp.retrlines("LIST -la", lines.append)
            out["list"] = "\n".join(lines)
            try:
                ftp.sendcmd("RETR keep.nc.part")
            except ftplib.error_perm as exc:
                out["retr"] = str(exc)
            ftp.delete("keep.nc.part")
            out["after"] = ",".join(ftp.nlst())
            ftp.quit()
            return out

        out = await in_thread(run)
    assert (
        out["feat"].startswith("211")
        and " SIZE" in out["feat"]
        and " MDTM" in out["feat"]
        and "UTF8" in out["feat"]
    )
    assert out["noop"].startswith("200") and out["opts"].startswith("200") and out["type"].startswith("200")
    assert out["mode"].startswith("200") and out["stru"].startswith("200") and out["allo"].startswith("202")
    assert out["pwd"] == "/" and out["pwd2"] == "/laser" and out["syst"].startswith("215")
    assert out["size"] == "7"
    assert out["mlsd"] == "keep.nc.part;tmp" or out["mlsd"] == "tmp;keep.nc.part"
    assert "keep.nc.part" in out["list"] and out["list"].startswith(("-rw", "drw"))
    assert out["retr"].startswith("550") and "write-only" in out["retr"]
    assert out["after"] == "tmp"

"""The FTP program store with real clients: ftplib (in a thread), aioftp and curl."""

from __future__ import annotations

import asyncio
import ftplib
import io
import shutil
from collections.abc import AsyncIterator
from pathlib import Path

import aioftp
import pytest

from simulator.ftp_store import FtpStore
from simulator.store import DirectoryStore
from tests.ftp_attacks import ATTACKER, login, race_stor
from tests.waiting import free_port

USER, PASSWORD = "cnc", "s3cret"


@pytest.fixture
async def store(tmp_path: Path) -> AsyncIterator[tuple[FtpStore, DirectoryStore]]:
    programs = DirectoryStore(tmp_path)
    programs.prepare()
    async with FtpStore(tmp_path, host="127.0.0.1", port=free_port(), user=USER, password=PASSWORD) as ftp:
        yield ftp, programs


def connect(port: int, user: str = USER, password: str = PASSWORD) -> ftplib.FTP:
    ftp = ftplib.FTP()
    ftp.connect("127.0.0.1", port, timeout=5)
    ftp.login(user, password)
    return ftp


@pytest.mark.parametrize(("user", "password"), [(USER, "wrong"), ("anonymous", "guest@"), ("root", PASSWORD)])
async def test_bad_logins_are_refused(
    store: tuple[FtpStore, DirectoryStore], user: str, password: str
) -> None:
    ftp, _ = store
    with pytest.raises(ftplib.error_perm, match=r"^530"):
        await asyncio.to_thread(connect, ftp.port, user, password)


async def test_upload_to_temp_name_then_rename_size_list_and_delete(
    store: tuple[FtpStore, DirectoryStore],
) -> None:
    ftp, programs = store
    new_demo = b"G0 X1\nM30\n"

    def session() -> tuple[int, list[str], list[str], int, list[str]]:
        with connect(ftp.port) as c:
            c.cwd("/DATA/Programs")
            c.storbinary("STOR part.nc.tmp", io.BytesIO(b"G0 X5\nM30\n"))
            c.rename("part.nc.tmp", "part.nc")
            size = c.size("part.nc")
            names = c.nlst()
            lines: list[str] = []
            c.dir(lines.append)
            c.storbinary("STOR demo.nc.tmp", io.BytesIO(new_demo))
            c.rename("demo.nc.tmp", "demo.nc")  # replaces the existing program
            demo_size = c.size("/DATA/Programs/demo.nc")
            c.delete("soft-limit.nc")
            with pytest.raises(ftplib.error_perm, match=r"^550"):
                c.size("soft-limit.nc")
            return size, names, lines, demo_size, c.nlst()

    size, names, lines, demo_size, after = await asyncio.to_thread(session)
    assert size == len(b"G0 X5\nM30\n")
    assert names == ["demo.nc", "part.nc", "soft-limit.nc"]
    assert any(line.endswith(" part.nc") and line.startswith("-") for line in lines)
    assert demo_size == len(new_demo)
    assert after == ["demo.nc", "part.nc"]
    assert programs.read("part.nc") == "G0 X5\nM30\n" and programs.read("demo.nc") == new_demo.decode()
    assert not programs.exists("soft-limit.nc")


async def test_aioftp_client_lists_with_mlsd_and_stats(store: tuple[FtpStore, DirectoryStore]) -> None:
    ftp, _ = store
    async with aioftp.Client.context("127.0.0.1", ftp.port, USER, PASSWORD) as client:
        listing = {path.name: info for path, info in await client.list("/DATA/Programs")}
        assert set(listing) == {"demo.nc", "soft-limit.nc"}
        assert listing["demo.nc"]["type"] == "file"
        stat = await client.stat("/DATA/Programs/demo.nc")
        assert int(stat["size"]) == (Path(__file__).parents[3] / "simulator/programs/demo.nc").stat().st_size


@pytest.mark.skipif(shutil.which("curl") is None, reason="curl is not installed")
async def test_curl_lists_and_downloads(store: tuple[FtpStore, DirectoryStore]) -> None:
    ftp, programs = store
    base = f"ftp://127.0.0.1:{ftp.port}/DATA/Programs/"
    for args, expected in (
        (["--list-only", base], "demo.nc\nsoft-limit.nc\n"),
        ([base + "soft-limit.nc"], programs.read("soft-limit.nc")),
    ):
        proc = await asyncio.create_subprocess_exec(
            "curl",
            "-sS",
            "--user",
            f"{USER}:{PASSWORD}",
            *args,
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE,
        )
        out, err = await asyncio.wait_for(proc.communicate(), 10)
        assert proc.returncode == 0, err
        assert out.decode().replace("\r\n", "\n") == expected


async def test_closing_with_a_client_still_connected_is_quiet(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    async with FtpStore(tmp_path, host="127.0.0.1", port=free_port(), user=USER, password=PASSWORD) as ftp:
        client = await asyncio.to_thread(connect, ftp.port)
    with pytest.raises((EOFError, OSError)):
        await asyncio.to_thread(client.pwd)
    client.close()
    assert not [r for r in caplog.records if r.levelname in ("ERROR", "CRITICAL")]


@pytest.mark.parametrize("verb", ["PASV", "EPSV"])
async def test_a_data_connection_from_another_address_is_refused(
    store: tuple[FtpStore, DirectoryStore], verb: str, caplog: pytest.LogCaptureFixture
) -> None:
    """The gateway delivers jobs to this store: a host that races it to the passive port must not get
    its own program stored in their place (the demo publishes the store's port)."""
    ftp, programs = store
    ours, theirs = b"G0 X1\nM30\n", b"G0 X999\nM30\n"

    def run() -> object:
        with login(ftp.port, USER, PASSWORD) as c:
            c.cwd("/DATA/Programs")
            return race_stor(c, "part.nc", ours, theirs, verb=verb)

    race = await asyncio.to_thread(run)
    assert race.final.startswith("226"), race
    assert programs.read("part.nc") == ours.decode()
    assert ftp.foreign_data_connections == 1
    assert f"refused a data connection from {ATTACKER}" in caplog.text

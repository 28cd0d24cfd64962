"""One failed-login lockout for every door (issue 23): guesses on one door lock the others out too.

A running gateway with users (OPC UA, the web console) and an FTP inbox account; `access.lockout`
made 3 failures. The guesses come from 127.0.0.1 through one door (or one through each); then the
right password is refused on every door from that address, and still accepted from 127.0.0.2
(the lockout is per address). Real clients: aiohttp, asyncua, ftplib.
"""

from __future__ import annotations

import ftplib
import logging
from pathlib import Path

import aiohttp
import pytest
from asyncua import ua

from tests.ftp_attacks import ATTACKER, VICTIM, login
from tests.integration.jobs.conftest import PASSWORD, PASSWORD_HASH, USER, in_thread
from tests.integration.security.conftest import USERS, Rig, secure_gateway
from tests.waiting import free_port

LOCKOUT = {"failures": 3, "window": 60, "duration": 300}
DOORS = ("http", "opcua", "ftp")


async def http_login(url: str, user: str, password: str, source: str = VICTIM) -> bool:
    connector = aiohttp.TCPConnector(local_addr=(source, 0))
    async with (
        aiohttp.ClientSession(url, connector=connector) as session,
        session.post("/login", data={"username": user, "password": password}, allow_redirects=False) as r,
    ):
        assert r.status in (303, 302, 401), r.status
        return r.status != 401


async def opcua_login(rig: Rig, user: str, password: str) -> bool:
    """From 127.0.0.1 (asyncua's client cannot choose its source address)."""
    try:
        async with rig.client(user, password):
            return True
    except ua.uaerrors.BadUserAccessDenied:
        return False


async def ftp_login(port: int, user: str, password: str, source: str = VICTIM) -> bool:
    def run() -> bool:
        try:
            login(port, user, password, source=source).close()
        except ftplib.error_perm:
            return False
        return True

    return await in_thread(run)


async def attempt(rig: Rig, url: str, door: str, *, right: bool) -> bool:
    """One login through `door` from 127.0.0.1, with the right password or a guess; whether it got in."""
    if door == "http":
        return await http_login(url, "otto", USERS["otto"][1] if right else "guess-http")
    if door == "opcua":
        return await opcua_login(rig, "otto", USERS["otto"][1] if right else "guess-opcua")
    assert rig.gateway.jobs is not None and rig.gateway.jobs.inbox is not None
    return await ftp_login(rig.gateway.jobs.inbox.port, USER, PASSWORD if right else "guess-ftp")


@pytest.mark.parametrize("guessing", [*DOORS, "each"])
async def test_guesses_on_one_door_lock_every_door_out_for_that_address(
    tmp_path: Path, guessing: str, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="gateway.auth")
    http_port = free_port()
    url = f"http://127.0.0.1:{http_port}"
    settings = {
        "access": {"lockout": LOCKOUT},
        "http": {"host": "127.0.0.1", "port": http_port},
        "inbox": {
            "host": "127.0.0.1",
            "port": 0,
            "accounts": [{"user": USER, "password_hash": PASSWORD_HASH}],
        },
    }
    async with secure_gateway(tmp_path, simulator=False, gateway=settings) as rig:
        for door in DOORS:  # every door lets the right password in before any guess
            assert await attempt(rig, url, door, right=True), door
        guesses = list(DOORS) if guessing == "each" else [guessing] * LOCKOUT["failures"]
        for door in guesses:
            assert not await attempt(rig, url, door, right=False), door

        got_in = {door: await attempt(rig, url, door, right=True) for door in DOORS}
        assert got_in == {"http": False, "opcua": False, "ftp": False}
        assert "refusing every login from 127.0.0.1 for 300 s" in caplog.text
        for via in ("HTTP", "OPC UA", "FTP"):
            assert any(
                m.startswith(f"{via}: login as") and "from 127.0.0.1 refused unchecked: locked out" in m
                for m in caplog.messages
            ), via
        # Another address is not locked out.
        assert await http_login(url, "otto", USERS["otto"][1], source=ATTACKER)
        assert rig.gateway.jobs is not None and rig.gateway.jobs.inbox is not None
        assert await ftp_login(rig.gateway.jobs.inbox.port, USER, PASSWORD, source=ATTACKER)

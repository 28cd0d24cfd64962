"""The inbox against an attacker on the shop network (issue 23): real sockets from two loopback hosts.

The victim (nesting software) works from 127.0.0.1, the attacker from 127.0.0.2 (tests/ftp_attacks.py):
- a passive data connection is taken only from the control connection's address (vsftpd's
  `pasv_promiscuous=NO`), so nobody can slip their bytes into someone else's upload;
- password guesses lock the guessing address out (the gateway's shared lockout, `access.lockout`);
- a session that has not logged in within `login_timeout` is closed, and one address holds at most
  `max_connections_per_address` sessions, so sessions that never log in cannot keep the slots;
- APPE counts from the file's size, so a temporary file stays within `max_file_size`; temporary files
  left behind are swept after `temp_max_age`.
"""

from __future__ import annotations

import contextlib
import ftplib
import hashlib
import io
import logging
import os
import time
from pathlib import Path

import pytest

from gateway.jobs.queue.store import JobState
from tests.ftp_attacks import ATTACKER, VICTIM, connect, login, noop_until_closed, open_sessions, race_stor
from tests.integration.jobs.conftest import PASSWORD, USER, Store, in_thread, mapping_text, program
from tests.waiting import wait_until, wait_until_sync

S = JobState


def sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


# --- passive data connections -------------------------------------------------------------------------


@pytest.mark.parametrize("verb", ["PASV", "EPSV"])
async def test_a_data_connection_from_another_address_is_refused_and_the_victims_upload_stored(
    store: Store, harness, verb: str, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING, logger="gateway.jobs.inbox")
    victim, attacker = program("victim"), program("attacker")
    async with harness([mapping_text("laser", store.port)]) as h:

        def run() -> object:
            ftp = login(h.port, USER, PASSWORD)
            try:
                ftp.cwd("/laser")
                return race_stor(ftp, "part42.nc", victim, attacker, verb=verb)
            finally:
                ftp.close()

        race = await in_thread(run)
        assert race.final.startswith("226 J000001 queued for laser"), race
        job = await h.wait_state(1, S.DELIVERED)
        assert job.sha256 == sha(victim) and job.user == USER
        assert store.files()["part42.nc"] == victim
        assert [j.sha256 for j in h.jobs()] == [sha(victim)]  # no job was ever made of the attacker's bytes
        assert h.service.inbox.refusals["foreign data connection"] == 1
        assert f"data connection from {ATTACKER}" in caplog.text and f"{VICTIM}" in caplog.text


async def test_without_a_data_connection_from_its_own_address_the_upload_fails_with_425(
    store: Store, harness
) -> None:
    attacker = program("attacker")
    async with harness([mapping_text("laser", store.port)], transfer_timeout=2) as h:

        def run() -> object:
            ftp = login(h.port, USER, PASSWORD)
            try:
                ftp.cwd("/laser")
                race = race_stor(ftp, "part42.nc", b"", attacker, victim_connects=False)
                return race, ftp.sendcmd("NOOP")  # the session goes on
            finally:
                ftp.close()

        race, noop = await in_thread(run)
        assert race.first.startswith("150"), race
        assert race.final.startswith("425") and "another address" in race.final, race
        assert noop.startswith("200")
        assert h.jobs() == []
        assert [p.name for p in (h.state / "inbox" / "laser").iterdir()] == ["tmp"]
        assert h.service.inbox.refusals["foreign data connection"] == 1


async def test_pasv_promiscuous_takes_data_connections_from_any_address(store: Store, harness) -> None:
    """The opt-out, for clients whose data connections really come from elsewhere (some NAT set-ups)."""
    other = program("from-elsewhere")
    async with harness([mapping_text("laser", store.port)], pasv_promiscuous=True) as h:

        def run() -> object:
            ftp = login(h.port, USER, PASSWORD)
            try:
                ftp.cwd("/laser")
                return race_stor(ftp, "part.nc", b"", other, victim_connects=False)
            finally:
                ftp.close()

        race = await in_thread(run)
        assert race.final.startswith("226 J000001"), race
        assert (await h.wait_state(1, S.DELIVERED)).sha256 == sha(other)
        assert h.service.inbox.refusals["foreign data connection"] == 0


# --- logins: the lockout, and sessions that never log in ------------------------------------------------


async def test_password_guesses_lock_the_guessing_address_out(
    store: Store, harness, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO)
    async with harness([mapping_text("laser", store.port)]) as h:  # access.lockout: 5 failures in 60 s

        def guess() -> list[str]:
            replies = []
            for attempt in range(5):
                try:
                    login(h.port, USER, f"guess-{attempt}", source=ATTACKER).close()
                    replies.append("230 logged in")
                except ftplib.Error as exc:
                    replies.append(str(exc))
            try:  # the right password, from the address that guessed
                login(h.port, USER, PASSWORD, source=ATTACKER).close()
                replies.append("230 logged in")
            except ftplib.Error as exc:
                replies.append(str(exc))
            return replies

        *guesses, right = await in_thread(guess)
        assert all(r.startswith("530 login incorrect") for r in guesses), guesses
        assert right.startswith("530") and "too many failed logins" in right, right
        # Another address is not locked out.
        assert (await h.stor("laser", "part.nc", program("ok"))).startswith("226 J000001")
        assert "refused unchecked: locked out" in caplog.text
        assert "guess-" not in caplog.text  # passwords never reach the log
        assert h.service.inbox.refusals["locked out"] == 1


async def test_sessions_that_never_log_in_cannot_keep_the_real_client_out(store: Store, harness) -> None:
    """Four sessions from one address that only send NOOP, against max_connections 4: the per-address cap
    turns two away at once, the pre-login timeout closes the others; the real client gets in throughout."""
    limits = {"max_connections": 4, "max_connections_per_address": 2, "login_timeout": 1}
    async with harness([mapping_text("laser", store.port)], **limits) as h:
        held, refused = await in_thread(lambda: open_sessions(h.port, 4, source=ATTACKER))
        try:
            assert len(refused) == 2 and all(
                r.startswith("421") and "from your address" in r for r in refused
            ), refused
            assert (await h.stor("laser", "part.nc", program("real"))).startswith("226 J000001")

            ends = [e.text if e else "" for e in await in_thread(noop_until_closed, held, 15)]
            assert all("not logged in within 1 s" in e for e in ends), ends
        finally:
            for ftp in held:
                ftp.close()
        assert h.service.inbox.refusals["too many from one address"] == 2
        assert h.service.inbox.refusals["no login in time"] == 2


async def test_one_address_never_takes_every_slot(store: Store, harness) -> None:
    """The issue's repro with the default per-address cap (8): max_connections 4, four sessions from one
    address that only send NOOP. The fourth is turned away; the real client gets in at once."""
    async with harness([mapping_text("laser", store.port)], max_connections=4) as h:
        held, refused = await in_thread(lambda: open_sessions(h.port, 4, source=ATTACKER))
        try:
            assert refused == ["421 too many connections from your address (at most 3)"], refused
            assert (await h.stor("laser", "part.nc", program("real"))).startswith("226 J000001")
        finally:
            for ftp in held:
                ftp.close()


async def test_slots_held_from_many_addresses_are_freed_by_the_login_timeout(store: Store, harness) -> None:
    async with harness([mapping_text("laser", store.port)], max_connections=3, login_timeout=1) as h:
        sources = ["127.0.0.3", "127.0.0.4", "127.0.0.5"]
        held = [await in_thread(lambda s=s: connect(h.port, source=s)) for s in sources]
        try:

            def gets_in() -> str:
                try:
                    ftp = login(h.port, USER, PASSWORD)
                except ftplib.Error as exc:
                    for other in held:  # the holders keep their sessions busy
                        with contextlib.suppress(ftplib.Error, OSError, EOFError):
                            other.sendcmd("NOOP")
                    return "" if str(exc).startswith("421") else str(exc)
                ftp.close()
                return "230"

            first = await in_thread(gets_in)
            assert first == "", "the three held slots did not keep the fourth session out"
            got = await in_thread(
                lambda: wait_until_sync(gets_in, timeout=15, interval=0.2, message="a slot for the client")
            )
            assert got == "230"
        finally:
            for ftp in held:
                ftp.close()


# --- temporary files -------------------------------------------------------------------------------


async def test_appe_counts_from_the_files_size(store: Store, harness) -> None:
    mib = 1024 * 1024
    chunk = (b"G1 X1 Y1 F1200\n" * (mib // 15 + 1))[:mib]
    async with harness([mapping_text("laser", store.port)], max_file_size="1MiB") as h:

        def append(ftp: ftplib.FTP, name: str, data: bytes) -> str:
            try:
                return ftp.storbinary(f"APPE {name}", io.BytesIO(data))
            except ftplib.Error as exc:
                return str(exc)
            except OSError:  # the server cut the data connection: its reason follows
                try:
                    return ftp.getresp()
                except ftplib.Error as exc:
                    return str(exc)

        def appends() -> tuple[list[str], int, list[str], int]:
            ftp = login(h.port, USER, PASSWORD)
            try:
                ftp.cwd("/laser")
                full = [append(ftp, "big.nc.part", chunk) for _ in range(5)]
                half = [append(ftp, "half.nc.part", chunk[: mib // 2]), append(ftp, "half.nc.part", chunk)]
                return full, ftp.size("big.nc.part") or 0, half, ftp.size("half.nc.part") or 0
            finally:
                ftp.close()

        full, size, half, half_size = await in_thread(appends)
        assert full[0].startswith("226"), full
        assert all(r.startswith("552") for r in full[1:]), full
        assert size == mib == (h.state / "inbox" / "laser" / "big.nc.part").stat().st_size
        # An append that would cross the limit is refused as a whole: the file is as it was before it.
        assert half[0].startswith("226") and half[1].startswith("552"), half
        assert half_size == mib // 2


async def test_stale_temporary_files_are_swept_at_start_and_while_running(
    store: Store, harness, tmp_path: Path
) -> None:
    folder = tmp_path / "state" / "inbox" / "laser"
    (folder / "tmp").mkdir(parents=True)
    old = time.time() - 3 * 3600
    for stale in (folder / "left.nc.part", folder / "tmp" / "left.nc"):
        stale.write_bytes(b"G1 X1\n")
        os.utime(stale, (old, old))
    (folder / "fresh.nc.part").write_bytes(b"G1 X1\n")
    async with harness([mapping_text("laser", store.port)], temp_max_age=7200) as h:
        names = sorted(p.name for p in folder.iterdir()) + sorted(p.name for p in (folder / "tmp").iterdir())
        assert names == ["fresh.nc.part", "tmp"]  # swept before the first client could log in
        assert h.service.inbox.swept == 2
    async with harness([mapping_text("laser", store.port)], temp_max_age=1) as h:

        def upload() -> str:
            ftp = login(h.port, USER, PASSWORD)
            try:
                return ftp.storbinary("STOR /laser/tmp/later.nc", io.BytesIO(program("later")))
            finally:
                ftp.close()

        assert (await in_thread(upload)).startswith("226")
        await wait_until(
            lambda: not (folder / "tmp" / "later.nc").exists() and not (folder / "fresh.nc.part").exists(),
            timeout=15,
            message="the temporary files swept",
        )
        assert h.jobs() == []

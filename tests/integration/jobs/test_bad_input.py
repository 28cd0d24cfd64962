"""Bad input at the inbox: each is refused or rejected with a reason, nothing reaches the controller,
and the inbox keeps serving."""

from __future__ import annotations

import asyncio
import contextlib
import ftplib
import io
import logging
import os
import socket
from pathlib import Path

import pytest

from gateway.jobs.queue.store import JobState
from tests.integration.jobs.conftest import GOOD, PASSWORD, USER, Harness, Store, in_thread, mapping_text
from tests.waiting import wait_until

S = JobState


async def still_serving(h: Harness, store: Store, name: str = "after.nc") -> None:
    """A good upload after the bad one is delivered: the inbox and the queue carry on."""
    reply = await h.stor("laser", name, GOOD)
    assert reply.startswith("226 J"), reply
    seq = int(reply.split()[1][1:])
    await h.wait_state(seq, S.DELIVERED)
    assert store.files()[name] == GOOD


def controller_untouched(store: Store, renames) -> None:
    assert renames.targets == []
    assert sorted(store.files()) == ["demo.nc", "soft-limit.nc"]


async def test_wrong_passwords_are_refused_and_a_third_ends_the_session(
    store: Store, harness, renames
) -> None:
    async with harness([mapping_text("laser", store.port)]) as h:

        def run() -> list[str]:
            out = []
            ftp = ftplib.FTP()
            ftp.connect("127.0.0.1", h.port, timeout=20)
            for attempt in range(3):
                try:
                    ftp.login(USER, f"wrong{attempt}")
                except ftplib.error_perm as exc:
                    out.append(str(exc))
            try:
                ftp.sendcmd("NOOP")
            except (EOFError, OSError, ftplib.Error) as exc:
                out.append(type(exc).__name__)
            for user, password in (("nobody", PASSWORD), ("anonymous", "me@example.com")):
                ftp = ftplib.FTP()  # from another address: five failures from one would lock it out
                ftp.connect("127.0.0.1", h.port, timeout=20, source_address=("127.0.0.2", 0))
                try:
                    ftp.login(user, password)
                except ftplib.error_perm as exc:
                    out.append(str(exc))
                ftp.close()
            return out

        out = await in_thread(run)
        assert out[:3] == ["530 login incorrect"] * 3
        assert out[3] in ("EOFError", "ConnectionResetError", "BrokenPipeError", "error_temp")
        assert out[4:] == ["530 login incorrect"] * 2  # unknown users get the very same answer
        controller_untouched(store, renames)
        await still_serving(h, store)


@pytest.mark.parametrize(
    ("command", "code"),
    [
        ("STOR ../escape.nc", "553"),
        ("STOR /laser/../../escape.nc", "553"),
        ("STOR ..\\..\\escape.nc", "553"),
        ("STOR C:/escape.nc", "553"),
        ("STOR .hidden.nc", "553"),
        ("STOR CON.nc", "553"),
        ("STOR sub/x.nc", "550"),
        ("CWD ..", "553"),
        ("CWD /etc", "550"),
        ("MKD /laser/other", "550"),
    ],
)
async def test_paths_that_escape_or_look_odd_are_refused(
    store: Store, harness, renames, tmp_path: Path, command: str, code: str
) -> None:
    async with harness([mapping_text("laser", store.port)]) as h:

        def run() -> str:
            ftp = h.ftp()
            ftp.cwd("/laser")
            try:
                if command.startswith("STOR"):
                    ftp.storbinary(command, io.BytesIO(GOOD))
                    return "stored"
                return ftp.sendcmd(command)
            except ftplib.Error as exc:
                return str(exc)
            finally:
                ftp.close()

        reply = await in_thread(run)
        assert reply.startswith(code), reply
        assert not (tmp_path / "escape.nc").exists() and not (h.state / "escape.nc").exists()
        assert h.jobs() == []
        controller_untouched(store, renames)
        await still_serving(h, store)


async def test_symbolic_links_in_the_inbox_are_not_followed(store: Store, harness, tmp_path: Path) -> None:
    secret = tmp_path / "secret.nc"
    secret.write_bytes(GOOD)
    async with harness([mapping_text("laser", store.port)]) as h:
        os.symlink(secret, h.state / "inbox" / "laser" / "link.nc.part")

        def run() -> str:
            ftp = h.ftp()
            try:
                ftp.rename("/laser/link.nc.part", "/laser/link.nc")
                return "renamed"
            except ftplib.Error as exc:
                return str(exc)
            finally:
                ftp.close()

        assert "symbolic links" in await in_thread(run)
        assert h.jobs() == [] and secret.read_bytes() == GOOD


async def test_oversized_uploads_are_refused(store: Store, harness, renames) -> None:
    async with harness([mapping_text("laser", store.port)], max_file_size=1000) as h:
        big = GOOD.replace(b"G21", b"(" + b"x" * 1200 + b")\nG21")
        reply = await h.stor("laser", "big.nc", big)
        assert reply.startswith("552") and "1000 bytes" in reply

        def allo() -> str:
            ftp = h.ftp()
            try:
                return ftp.sendcmd("ALLO 5000")
            except ftplib.Error as exc:
                return str(exc)
            finally:
                ftp.close()

        assert (await in_thread(allo)).startswith("552")
        assert h.jobs() == []
        assert list((h.state / "inbox" / ".staging").iterdir()) == []
        controller_untouched(store, renames)
        await still_serving(h, store)


@pytest.mark.parametrize("reset", [True, False], ids=["reset", "fin"])
async def test_a_client_that_dies_mid_stor_creates_no_job(
    store: Store, harness, renames, caplog, reset: bool
) -> None:
    caplog.set_level(logging.INFO, logger="gateway.jobs.inbox")
    async with harness([mapping_text("laser", store.port)]) as h:

        def die_mid_upload() -> None:
            control = socket.create_connection(("127.0.0.1", h.port), timeout=20)
            f = control.makefile("rb")

            def reply() -> str:
                line = f.readline().decode()
                while line[3:4] == "-":
                    line = f.readline().decode()
                return line

            def send(cmd: str) -> str:
                control.sendall(cmd.encode() + b"\r\n")
                return reply()

            reply()  # greeting
            send(f"USER {USER}")
            assert send(f"PASS {PASSWORD}").startswith("230")
            send("TYPE I")
            port = int(send("EPSV").split("|||")[1].split("|")[0])
            data = socket.create_connection(("127.0.0.1", port), timeout=20)
            assert send("STOR /laser/cut-off.nc").startswith("150")
            data.sendall(GOOD[: len(GOOD) // 2])
            # the process dies: both connections go at once
            for sock in (data, control):
                if reset:  # unread data, or linger 0: the kernel resets the connection
                    sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\x01\x00\x00\x00\x00\x00\x00\x00")
                sock.close()

        await in_thread(die_mid_upload)
        await wait_until(
            lambda: "did not complete; discarded" in caplog.text or "failed" in caplog.text,
            message="the inbox to notice the dead client",
        )
        assert h.jobs() == []
        assert list((h.state / "inbox" / ".staging").iterdir()) == []
        assert list((h.state / "inbox" / "laser").iterdir()) == [h.state / "inbox" / "laser" / "tmp"]
        controller_untouched(store, renames)
        await still_serving(h, store)


BAD_PROGRAMS = [
    ("binary.nc", b"\x7fELF\x02\x01\x01\x00" + bytes(range(256)) * 4, "binary"),
    ("no-end.nc", b"G21 G90\nG0 X10 Y10\nG1 X50 F3000\n", "end-code"),
    ("half.nc", GOOD[: GOOD.index(b"M30")], "end-marker"),  # `%` opened, never closed: cut off
    ("xoff.nc", GOOD.replace(b"G21", b"G21\x13"), "xon-xoff"),
    ("umlaut.nc", GOOD.replace(b"G21 G90", "G21 G90 Xä".encode()), "character"),
    ("name-far-too-long-for-the-controller-01.nc", GOOD, "file-name"),
    ("part.exe", GOOD, "file-name"),
    ("part with spaces.nc", GOOD, "file-name"),
]


@pytest.mark.parametrize(
    ("name", "data", "rule"), BAD_PROGRAMS, ids=[b[2] + ":" + b[0] for b in BAD_PROGRAMS]
)
async def test_bad_programs_are_rejected_with_a_reason_and_kept(
    store: Store, harness, renames, name: str, data: bytes, rule: str
) -> None:
    async with harness([mapping_text("laser", store.port)]) as h:
        reply = await h.stor("laser", name, data)
        assert reply.startswith("550 J000001 rejected: "), reply
        job = h.job(1)
        assert job.state is S.REJECTED and job.reason and job.reason in reply
        kept = h.state / "rejected" / f"J000001-{name}"
        assert kept.read_bytes() == data
        reason = Path(f"{kept}.reason").read_text()
        assert f"[{rule}]" in reason and "J000001" in reason
        await wait_until(
            lambda: h.value("laser", "Jobs/LastRejected") == f"J000001 {name}", message="LastRejected"
        )
        assert h.value("laser", "Jobs/LastRejectedReason") == job.reason
        controller_untouched(store, renames)
        await still_serving(h, store)


async def test_session_limits_files_and_idle_time(store: Store, harness) -> None:
    async with harness([mapping_text("laser", store.port)], max_files_per_session=2, idle_timeout=0.5) as h:

        def run() -> list[str]:
            ftp = h.ftp()
            ftp.cwd("/laser")
            out = []
            for n in range(3):
                try:
                    out.append(ftp.storbinary(f"STOR s{n}.nc.part", io.BytesIO(b"x")))
                except ftplib.Error as exc:
                    out.append(str(exc))
            out.append(ftp.getline())  # nothing more to say: the server ends the idle session
            return out

        out = await in_thread(run)
        assert out[0].startswith("226") and out[1].startswith("226")
        assert out[2].startswith("552") and "2 files per session" in out[2]
        assert out[3].startswith("421") and "idle" in out[3]


async def test_a_long_upload_is_not_an_idle_session(store: Store, harness) -> None:
    """The control connection is silent during a transfer; that is not idleness."""
    async with harness([mapping_text("laser", store.port)], idle_timeout=0.3) as h:

        def run() -> str:
            ftp = h.ftp()
            ftp.cwd("/laser")
            with ftp.transfercmd("STOR slow.nc") as conn:
                for chunk in (GOOD[:10], GOOD[10:30], GOOD[30:]):
                    conn.sendall(chunk)
                    ftp.sock.settimeout(0.4)  # longer than the idle timeout, in the middle of the upload
                    with contextlib.suppress(TimeoutError):
                        ftp.sock.recv(1, socket.MSG_PEEK)
                    ftp.sock.settimeout(20)
            return ftp.voidresp()

        assert (await in_thread(run)).startswith("226 J000001 queued")
        await h.wait_state(1, S.DELIVERED)


async def test_anonymous_login_when_enabled(store: Store, harness, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="gateway")
    async with harness([mapping_text("laser", store.port)], accounts=[], anonymous=True) as h:
        assert any(
            r.levelno == logging.WARNING
            and "anonymous logins (any password) may submit programs for laser" in r.getMessage()
            for r in caplog.records
        ), "start-up says the inbox is open to anyone"
        reply = await h.stor("laser", "anon.nc", GOOD, user="anonymous", password="guest@")
        assert reply.startswith("226 J000001")
        assert h.job(1).user == "anonymous"


async def test_no_accounts_means_no_inbox(store: Store, harness) -> None:
    async with harness([mapping_text("laser", store.port)], accounts=[]) as h:
        assert h.service.inbox is None


async def test_a_missing_password_variable_stops_the_start_with_a_clear_error(store: Store, harness) -> None:
    from gateway.errors import SinkError

    with pytest.raises(SinkError, match="NEST_PASSWORD"):
        async with harness(
            [mapping_text("laser", store.port)], accounts=[{"user": "nest", "password_env": "NEST_PASSWORD"}]
        ):
            pass


async def test_environment_passwords_work(store: Store, harness) -> None:
    async with harness(
        [mapping_text("laser", store.port)],
        environ={"NEST_PASSWORD": "from-env"},
        accounts=[{"user": "nest", "password_env": "NEST_PASSWORD"}],
    ) as h:
        assert (await h.stor("laser", "env.nc", GOOD, user="nest", password="from-env")).startswith("226")
        with pytest.raises(ftplib.error_perm, match="530"):
            await h.stor("laser", "env.nc", GOOD, user="nest", password=PASSWORD)


async def test_a_port_in_use_is_a_clear_error(store: Store, harness) -> None:
    from gateway.errors import SinkError

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        with pytest.raises(SinkError, match="cannot listen"):
            async with harness([mapping_text("laser", store.port)], port=taken.getsockname()[1]):
                pass
    await asyncio.sleep(0)

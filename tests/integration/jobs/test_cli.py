"""`cnc-gateway programs …`, `jobs submit` and `hash-password`, as commands, against real servers."""

from __future__ import annotations

import asyncio
import datetime
import getpass
import io
import json
import ssl
import subprocess
import sys
from pathlib import Path

import pytest

from gateway.auth.passwords import verify_password
from gateway.cli.jobs import Progress
from gateway.jobs.queue.store import JobState
from tests.integration.jobs.conftest import GOOD, PASSWORD, USER, Store, in_thread, mapping_text
from tests.waiting import free_port


async def cli(
    *args: str, stdin: bytes | None = None, env: dict[str, str] | None = None
) -> tuple[int, str, str]:
    import os

    proc = await asyncio.create_subprocess_exec(
        str(Path(sys.executable).with_name("cnc-gateway")),
        *args,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env={**os.environ, **(env or {})},
    )
    out, err = await proc.communicate(stdin)
    return proc.returncode or 0, out.decode(), err.decode()


async def test_programs_list_get_put_delete(store: Store, tmp_path: Path) -> None:
    mapping = tmp_path / "laser.yaml"
    mapping.write_text(mapping_text("laser", store.port))
    c = ("-c", str(mapping))
    code, out, err = await cli("programs", "list", "laser", *c)
    assert code == 0, err
    assert [line.split()[-1] for line in out.splitlines()] == ["demo.nc", "soft-limit.nc"]
    assert out.splitlines()[0].split()[0] == str(len(store.files()["demo.nc"]))

    target = tmp_path / "copy.nc"
    code, _, err = await cli("programs", "get", "laser", "demo.nc", "-o", str(target), *c)
    assert code == 0 and target.read_bytes() == store.files()["demo.nc"], err

    source = tmp_path / "new.nc"
    source.write_bytes(GOOD)
    changes = (*c, "--state-dir", str(tmp_path / "state"))  # where put and delete record themselves
    code, out, err = await cli("programs", "put", "laser", str(source), *changes)
    assert code == 0 and "stored new.nc" in out, err
    assert store.files()["new.nc"] == GOOD

    source.write_bytes(b"G1 X1 F100\n")
    code, _, err = await cli("programs", "put", "laser", str(source), "--name", "bad.nc", *changes)
    assert code == 1 and "would be rejected" in err and "end code" in err
    assert "bad.nc" not in store.files()

    code, out, err = await cli("programs", "delete", "laser", "new.nc", *changes)
    assert code == 0 and "deleted new.nc" in out, err
    assert "new.nc" not in store.files()
    code, _, err = await cli("programs", "delete", "laser", "new.nc", *changes)
    assert code == 1 and "new.nc is not in" in err
    code, _, err = await cli("programs", "list", "press", *c)
    assert code == 2 and "no machine 'press'" in err


async def test_programs_put_and_delete_are_audited(store: Store, tmp_path: Path) -> None:
    """Every change to a controller is in the audit trail, whatever door it came through: the shell's too."""
    mapping = tmp_path / "laser.yaml"
    mapping.write_text(mapping_text("laser", store.port))
    state = tmp_path / "state"
    c = ("-c", str(mapping), "--state-dir", str(state))
    source = tmp_path / "part.nc"
    source.write_bytes(GOOD)
    code, _, err = await cli("programs", "put", "laser", str(source), *c)
    assert code == 0, err
    source.write_bytes(b"G1 X1 F100\n")
    code, _, err = await cli(
        "programs", "put", "laser", str(source), "--name", "bad.nc", "--user", "erik", *c
    )
    assert code == 1, err
    code, _, err = await cli("programs", "delete", "laser", "part.nc", "--user", "erik", *c)
    assert code == 0, err
    code, _, err = await cli("programs", "delete", "laser", "part.nc", *c)
    assert code == 1, err

    code, out, err = await cli("audit", "list", "--state-dir", str(state), "--json")
    assert code == 0, err
    entries = [json.loads(line) for line in reversed(out.splitlines())]  # oldest first
    me = getpass.getuser()
    assert [(e["machine"], e["kind"], e["target"], e["user"], e["origin"], e["status"]) for e in entries] == [
        ("laser", "call", "Programs.Put", me, "cli", "Good"),
        ("laser", "call", "Programs.Put", "erik", "cli", "BadInvalidArgument"),
        ("laser", "call", "Programs.Delete", "erik", "cli", "Good"),
        ("laser", "call", "Programs.Delete", me, "cli", "BadNotFound"),
    ]
    assert json.loads(entries[0]["new"]) == ["part.nc", f"<{len(GOOD)} bytes>"]
    assert "end code" in entries[1]["reason"] and json.loads(entries[3]["new"]) == ["part.nc"]
    assert "part.nc is not in" in entries[3]["reason"]


async def test_programs_change_nothing_when_the_audit_trail_refuses_them(
    store: Store, tmp_path: Path
) -> None:
    """An audit file the trail will not open (written by a newer cnc-gateway): a message, no change."""
    import sqlite3

    mapping = tmp_path / "laser.yaml"
    mapping.write_text(mapping_text("laser", store.port))
    state = tmp_path / "state"
    state.mkdir()
    with sqlite3.connect(state / "audit.sqlite3") as db:
        db.execute("PRAGMA user_version=99")
    target = store.folder() / "keep.nc"
    target.write_bytes(GOOD)
    code, _, err = await cli(
        "programs", "delete", "laser", "keep.nc", "-c", str(mapping), "--state-dir", str(state)
    )
    assert code == 2 and "cannot open the audit trail" in err and "newer cnc-gateway" in err, err
    assert "Traceback" not in err
    assert target.read_bytes() == GOOD


async def test_programs_against_a_controller_that_is_down(tmp_path: Path) -> None:
    mapping = tmp_path / "laser.yaml"
    mapping.write_text(mapping_text("laser", free_port()))
    code, _, err = await cli("programs", "list", "laser", "-c", str(mapping))
    assert code == 1 and "unreachable" in err and "Traceback" not in err


async def test_jobs_submit_uploads_through_the_inbox(store: Store, harness, tmp_path: Path) -> None:
    source = tmp_path / "sheet.nc"
    source.write_bytes(GOOD)
    async with harness([mapping_text("laser", store.port)]) as h:
        base = ("jobs", "submit", "--machine", "laser", "--port", str(h.port), "--user", USER)
        code, out, err = await cli(
            *base, str(source), "--priority", "3", env={"CNC_INBOX_PASSWORD": PASSWORD}
        )
        assert code == 0 and out.startswith("J000001 queued for laser"), err
        await h.wait_state(1, JobState.DELIVERED)
        assert h.job(1).priority == 3 and store.files()["sheet.nc"] == GOOD
        source.write_bytes(b"G1 X1 F100\n")
        code, out, err = await cli(*base, str(source), "--name", "bad.nc", "--password", PASSWORD)
        assert code == 1 and out.startswith("J000002 rejected:")
        code, _, err = await cli(*base, str(source), "--password", "wrong")
        assert code == 2 and "530" in err


def test_the_progress_bar_for_large_files() -> None:
    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    out = Tty()
    bar = Progress(20_000_000, out)
    bar(10_000_000)
    bar(20_000_000)
    bar.done()
    text = out.getvalue()
    assert "50.0%" in text and "100.0%" in text and "20.0/20.0 MB" in text and text.endswith("\n")
    quiet = Tty()
    Progress(1000, quiet)(1000)  # small files: no bar
    assert quiet.getvalue() == ""


async def test_hash_password_prints_a_hash_that_verifies() -> None:
    code, out, err = await cli("hash-password", "--stdin", stdin=b"s3cret\n")
    assert code == 0, err
    assert verify_password("s3cret", out.strip()) and not verify_password("other", out.strip())


def self_signed(directory: Path) -> None:
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "cnc-gateway test")])
    now = datetime.datetime.now(datetime.UTC)
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=1))
        .sign(key, hashes.SHA256())
    )
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "inbox-cert.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    (directory / "inbox-key.pem").write_bytes(
        key.private_bytes(
            serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
        )
    )


async def test_implicit_ftps_inbox_with_a_passive_port_range(store: Store, harness, tmp_path: Path) -> None:
    from gateway.cli.upload import upload

    self_signed(tmp_path / "state")
    low = free_port()
    ports = {"min": low, "max": low + 2}
    async with harness([mapping_text("laser", store.port)], tls={}, passive_ports=ports) as h:
        source = tmp_path / "secure.nc"
        source.write_bytes(GOOD)
        ok, reply = await in_thread(
            lambda: upload(
                "127.0.0.1", h.port, USER, PASSWORD, "laser", source, "secure.nc", tls=True, verify=False
            )
        )
        assert ok and reply.startswith("J000001 queued"), reply
        await h.wait_state(1, JobState.DELIVERED)

        def plain_client() -> bytes:
            import socket

            with socket.create_connection(("127.0.0.1", h.port), timeout=10) as sock:
                sock.sendall(b"USER nest\r\n")  # not a TLS handshake: the server gives up on us
                try:
                    return sock.recv(100)
                except ConnectionResetError:
                    return b""

        assert not (await in_thread(plain_client)).startswith(b"220")

        def passive_port() -> int:

            context = ssl.create_default_context()
            context.check_hostname = False
            context.verify_mode = ssl.CERT_NONE
            from gateway.cli.upload import ImplicitFTPS

            ftp = ImplicitFTPS(context=context, timeout=10)
            ftp.connect("127.0.0.1", h.port)
            ftp.login(USER, PASSWORD)
            _, port = ftp.makepasv()
            ftp.close()
            return port

        assert low <= await in_thread(passive_port) <= low + 2


async def test_tls_without_a_certificate_says_how_to_make_one(store: Store, harness) -> None:
    from gateway.errors import SinkError

    with pytest.raises(SinkError, match="openssl req"):
        async with harness([mapping_text("laser", store.port)], tls={}):
            pass

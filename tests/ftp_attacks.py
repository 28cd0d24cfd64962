"""What an attacker on the shop network does to an FTP server, with plain sockets and ftplib.

Two hosts on one machine: Linux routes all of 127.0.0.0/8 to the loopback interface, so a
socket bound to 127.0.0.2 before it connects is "another host" to a server on 127.0.0.1.
The victim (nesting software) logs in from 127.0.0.1; the attacker connects from 127.0.0.2.

Blocking (ftplib): call these in a thread (tests.integration.jobs.conftest.in_thread).
"""

from __future__ import annotations

import contextlib
import ftplib
import socket
import time
from dataclasses import dataclass

VICTIM, ATTACKER = "127.0.0.1", "127.0.0.2"
TIMEOUT = 20.0  # s; only to end a hang


def login(port: int, user: str, password: str, *, source: str = VICTIM) -> ftplib.FTP:
    """A logged-in ftplib session to 127.0.0.1:`port` from `source`; ftplib.Error if refused."""
    ftp = connect(port, source=source)
    try:
        ftp.login(user, password)
    except BaseException:
        ftp.close()
        raise
    return ftp


def connect(port: int, *, source: str = VICTIM) -> ftplib.FTP:
    """A session that has read the greeting (ftplib.Error if it was a refusal), not logged in."""
    ftp = ftplib.FTP(encoding="utf-8")
    ftp.connect("127.0.0.1", port, timeout=TIMEOUT, source_address=(source, 0))
    return ftp


def passive(ftp: ftplib.FTP, verb: str = "PASV") -> tuple[str, int]:
    """Send PASV or EPSV; the (host, port) the server listens on for the data connection."""
    if verb == "EPSV":
        peer = ftp.sock.getpeername()
        return ftplib.parse229(ftp.sendcmd("EPSV"), peer)
    return ftplib.parse227(ftp.sendcmd("PASV"))


def steal(host: str, port: int, data: bytes, *, source: str = ATTACKER) -> socket.socket:
    """Connect to a passive port from `source` and send `data` (then EOF), as the attacker does first.

    Returned open: the caller closes it once the victim's transfer is over."""
    thief = socket.create_connection((host, port), timeout=TIMEOUT, source_address=(source, 0))
    try:
        thief.sendall(data)
        thief.shutdown(socket.SHUT_WR)
    except OSError:  # refused already: the server closed it
        pass
    return thief


@dataclass(frozen=True)
class Race:
    """The victim's side of a raced upload: the STOR's first and final replies (or an error's text)."""

    first: str
    final: str


def race_stor(
    ftp: ftplib.FTP,
    name: str,
    victim: bytes,
    attacker: bytes,
    *,
    verb: str = "PASV",
    victim_connects: bool = True,
    attacker_source: str = ATTACKER,
) -> Race:
    """The victim (`ftp`, logged in, in its folder) sends PASV/EPSV; the attacker connects to that port
    first and sends `attacker`; then the victim connects (unless `victim_connects` is False), sends STOR
    and its own bytes. The kernel's accept queue is first in, first out, so the attacker's connection is
    the first one the server sees."""
    ftp.voidcmd("TYPE I")
    host, port = passive(ftp, verb)
    thief = steal(host, port, attacker, source=attacker_source)
    try:
        conn = None
        if victim_connects:
            conn = socket.create_connection((host, port), timeout=TIMEOUT, source_address=(VICTIM, 0))
        try:
            try:
                first = ftp.sendcmd(f"STOR {name}")
            except ftplib.Error as exc:
                return Race(str(exc), str(exc))
            if conn is not None:
                with contextlib.suppress(OSError):  # closed by the server: it took another connection
                    conn.sendall(victim)
                conn.close()
                conn = None
            try:
                final = ftp.getresp()
            except ftplib.Error as exc:
                final = str(exc)
            return Race(first, final)
        finally:
            if conn is not None:
                conn.close()
    finally:
        thief.close()


def reply(ftp: ftplib.FTP, command: str) -> str:
    """The server's reply to `command`, or the refusal's text."""
    try:
        return ftp.sendcmd(command)
    except ftplib.Error as exc:
        return str(exc)


@dataclass(frozen=True)
class Ended:
    """How a session the server closed ended: its last reply (or the error), and when (time.monotonic())."""

    text: str
    at: float


def noop_until_closed(sessions: list[ftplib.FTP], timeout: float) -> list[Ended | None]:
    """Send NOOP on every session, again and again, until the server has closed each (None: still open
    when `timeout` passed), as a client that keeps its sessions busy without logging in does."""
    ends: list[Ended | None] = [None] * len(sessions)

    def all_closed() -> bool:
        for i, ftp in enumerate(sessions):
            if ends[i] is None:
                try:
                    ftp.sendcmd("NOOP")
                except (ftplib.Error, OSError, EOFError) as exc:
                    ends[i] = Ended(str(exc) or type(exc).__name__, time.monotonic())
        return all(e is not None for e in ends)

    deadline = time.monotonic() + timeout
    while not all_closed() and time.monotonic() < deadline:
        time.sleep(0.2)
    return ends


def open_sessions(port: int, count: int, *, source: str) -> tuple[list[ftplib.FTP], list[str]]:
    """Open `count` sessions from `source` without logging in: (the ones the server took, the refusals)."""
    held, refused = [], []
    for _ in range(count):
        try:
            held.append(connect(port, source=source))
        except ftplib.Error as exc:
            refused.append(str(exc))
    return held, refused

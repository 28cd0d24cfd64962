"""Security drill: an attacker on the shop network against a running gateway's FTP inbox and its password
doors (issue 23); the machine must see nothing of it.

One gateway (users, the web console, the FTP inbox with small limits) delivering to the simulator's FTP
program store; the victim (nesting software) works from 127.0.0.1, attackers from other loopback
addresses (Linux routes all of 127.0.0.0/8 to lo). In turn:

1. the passive-port race: for each of N uploads (PASV and EPSV in turn), another host connects to the
   victim's passive port first and sends a program of its own; every tenth time the victim never
   connects. Each victim upload must be delivered as the victim sent it, or fail with 425;
2. holding slots before login: A addresses each open max_connections_per_address + 2 sessions that only
   send NOOP. The extra ones are turned away at once, the others closed at login_timeout; meanwhile
   the real client uploads;
3. the attack corpus (tests/corpus/ftp/attacks.yaml);
4. password guessing on every door: G addresses guess on the web console and the FTP inbox in turn,
   127.0.0.1 on OPC UA (asyncua cannot choose its source address); the gateway checks exactly
   access.lockout.failures guesses per address, whatever the door, and then turns the right password
   away on every door too.

At the end: no job ever held an attacker's program, none reached the machine's program store, every
victim program that was answered 226 was delivered unchanged, and the log has no error or traceback.
Small counts in `make test`, large ones under CNC_DRILL_SCALE=soak (conftest.py). Figures are printed.
"""

from __future__ import annotations

import asyncio
import ftplib
import hashlib
import io
import logging
import re
import time
from collections import Counter
from pathlib import Path
from typing import Any

import aiohttp
import pytest
from asyncua import ua

from gateway.jobs.queue.store import JobState
from tests import ftp_attacks as attacks
from tests.integration.drills import corpus_runners as runners
from tests.integration.drills.conftest import Records, Report, count
from tests.integration.jobs.conftest import PASSWORD, PASSWORD_HASH, USER, in_thread, program
from tests.integration.security.conftest import USERS, Rig, secure_gateway
from tests.waiting import free_port, wait_until, wait_until_sync

MACHINE = "laser-sim"
LOCKOUT = {"failures": 5, "window": 60, "duration": 300}
INBOX = {
    "host": "127.0.0.1",
    "port": 0,
    "accounts": [{"user": USER, "password_hash": PASSWORD_HASH}],
    "max_connections": 16,
    "max_connections_per_address": 3,
    "login_timeout": 2,
    "transfer_timeout": 2,  # how long a transfer waits for its data connection
    "max_file_size": "1MiB",
}
EXTRA = 2  # sessions per holding address beyond its cap


def store_files(rig: Rig) -> dict[str, bytes]:
    folder = rig.state_dir.parent / "store" / "DATA" / "Programs"
    return {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()}


# --- 1. the passive-port race --------------------------------------------------------------------------


def race(port: int, index: int, victim: bytes, attacker: bytes) -> attacks.Race:
    ftp = attacks.login(port, USER, PASSWORD)
    try:
        ftp.cwd(f"/{MACHINE}")
        return attacks.race_stor(ftp, f"race{index}.nc", victim, attacker, verb=("PASV", "EPSV")[index % 2],
                                 victim_connects=index % 10 != 5,
                                 attacker_source=f"127.0.0.{2 + index % 200}")  # fmt: skip
    finally:
        ftp.close()


async def passive_races(rig: Rig, n: int, theirs: set[str]) -> dict[str, Any]:
    inbox = rig.gateway.jobs.inbox  # type: ignore[union-attr]
    expected: dict[int, bytes] = {}  # job seq -> the victim's program
    answers: Counter[str] = Counter()
    wrong: list[str] = []
    started = time.monotonic()
    for i in range(n):
        victim, attacker = program(f"victim {i}"), program(f"attacker {i}")
        theirs.add(hashlib.sha256(attacker).hexdigest())
        result = await in_thread(race, inbox.port, i, victim, attacker)
        answers[result.final[:3]] += 1
        if i % 10 == 5:
            if not (result.final.startswith("425") and "another address" in result.final):
                wrong.append(f"{i}: {result}")
        elif result.final.startswith("226 J"):
            expected[int(result.final.split()[1][1:])] = victim
        else:
            wrong.append(f"{i}: {result}")
    seconds = time.monotonic() - started
    assert not wrong, "races without the answer they must get:\n" + "\n".join(wrong[:10])
    queue = rig.gateway.jobs.queue  # type: ignore[union-attr]
    for seq in expected:
        await wait_until(lambda s=seq: queue.get(s).state is JobState.DELIVERED, timeout=60,
                         message=f"J{seq:06d} delivered")  # fmt: skip
    delivered = store_files(rig)
    changed = [seq for seq, data in expected.items() if delivered.get(queue.get(seq).filename) != data]
    assert not changed, f"victim programs not delivered as sent: {changed}"
    return {
        "races": n,
        "races_stored_victims_bytes": len(expected),
        "races_failed_425": answers["425"],
        "foreign_data_refused": inbox.refusals["foreign data connection"],
        "race_ms_each": round(1000 * seconds / max(n, 1)),
    }


# --- 2. slots held before a login ---------------------------------------------------------------------


async def held_slots(rig: Rig, addresses: int) -> dict[str, Any]:
    inbox = rig.gateway.jobs.inbox  # type: ignore[union-attr]
    cap, timeout = inbox.config.max_connections_per_address, inbox.config.login_timeout

    def open_sessions(address: str) -> tuple[list[tuple[ftplib.FTP, float]], list[str]]:
        held, refused = attacks.open_sessions(inbox.port, cap + EXTRA, source=address)
        now = time.monotonic()
        return [(ftp, now) for ftp in held], refused

    before = Counter(inbox.refusals)
    sources = [f"127.0.1.{1 + a}" for a in range(addresses)]
    opened = await asyncio.gather(*(in_thread(open_sessions, source) for source in sources))
    held = [h for sessions, _ in opened for h in sessions]
    refused = [r for _, rs in opened for r in rs]
    assert all(len(sessions) <= cap for sessions, _ in opened), [len(s) for s, _ in opened]
    assert all(r.startswith("421") for r in refused), refused[:5]
    try:
        # The real client, meanwhile: it gets in (at once while the attackers hold fewer than all the
        # slots; once the login timeout frees them otherwise).
        client_started = time.monotonic()

        def upload() -> str:
            try:
                ftp = attacks.login(inbox.port, USER, PASSWORD)
            except ftplib.error_temp as exc:  # 421: every slot taken
                return "" if str(exc).startswith("421") else str(exc)
            try:
                return ftp.storbinary(f"STOR /{MACHINE}/held.nc", io.BytesIO(program("held")))
            finally:
                ftp.close()

        reply = await in_thread(
            lambda: wait_until_sync(upload, timeout=timeout + 30, interval=0.1, message="the client's upload")
        )
        client_waited = time.monotonic() - client_started
        assert reply.startswith("226 J"), reply

        ends = await in_thread(attacks.noop_until_closed, [ftp for ftp, _ in held], timeout + 30)
    finally:
        for ftp, _ in held:
            ftp.close()
    closed = [e for e in ends if e is not None]
    assert len(closed) == len(held) and all("not logged in within" in e.text for e in closed), ends[:5]
    lasted = [e.at - since for (_, since), e in zip(held, closed, strict=True)]
    counted = Counter(inbox.refusals) - before
    assert counted["no login in time"] == len(held), counted  # each closed once, by the login timeout
    return {
        "held_addresses": addresses,
        "held_sessions": len(held),
        "held_refused_per_address_cap": sum("from your address" in r for r in refused),
        "held_refused_server_full": sum("from your address" not in r for r in refused),
        "held_closed_after_s": f"{min(lasted):.1f}-{max(lasted):.1f}",
        "client_waited_s": round(client_waited, 2),
        "no_login_closed": counted["no login in time"],
    }


# --- 4. password guessing on every door ---------------------------------------------------------------


async def http_login(url: str, password: str, source: str) -> bool:
    connector = aiohttp.TCPConnector(local_addr=(source, 0))
    async with (
        aiohttp.ClientSession(url, connector=connector) as session,
        session.post("/login", data={"username": "otto", "password": password}, allow_redirects=False) as r,
    ):
        return r.status != 401


async def ftp_login(port: int, password: str, source: str) -> bool:
    """Whether the login got in. A 421 (every session slot taken, by the many guessers at soak scale) is
    no answer to the password: tried again."""

    def attempt() -> str:
        try:
            attacks.login(port, USER, password, source=source).close()
        except ftplib.error_temp as exc:
            return "" if str(exc).startswith("421") else str(exc)
        except ftplib.error_perm as exc:
            return str(exc)
        return "230"

    reply = await in_thread(
        lambda: wait_until_sync(attempt, timeout=60, interval=0.1, message=f"an FTP answer from {source}")
    )
    return reply == "230"


async def opcua_login(rig: Rig, password: str) -> bool:
    try:
        async with rig.client("otto", password):
            return True
    except ua.uaerrors.BadUserAccessDenied:
        return False


async def guessing(rig: Rig, url: str, addresses: int, records: Records) -> dict[str, Any]:
    port = rig.gateway.jobs.inbox.port  # type: ignore[union-attr]
    failures = LOCKOUT["failures"]
    guesses = 3 * failures  # per address: three times what the lockout lets through

    async def guess_from(source: str) -> list[bool]:
        got_in = []
        for g in range(guesses):  # the web console and the FTP inbox in turn
            door = http_login(url, f"guess-{g}", source) if g % 2 else ftp_login(port, f"guess-{g}", source)
            got_in.append(await door)
        return got_in

    sources = [f"127.0.2.{1 + a}" for a in range(addresses)]
    started = time.monotonic()
    results = await asyncio.gather(*(guess_from(s) for s in sources))
    assert not any(any(r) for r in results), "a guess got in"
    for source in sources:  # the right password, on both doors, from a guessing address
        assert not await http_login(url, USERS["otto"][1], source)
        assert not await ftp_login(port, PASSWORD, source)
    # 127.0.0.1 on OPC UA, then the right password on every door from there.
    opcua_guesses = [await opcua_login(rig, f"guess-opcua-{g}") for g in range(guesses)]
    assert not any(opcua_guesses)
    assert not await opcua_login(rig, USERS["otto"][1])
    assert not await http_login(url, USERS["otto"][1], "127.0.0.1")
    assert not await ftp_login(port, PASSWORD, "127.0.0.1")
    seconds = time.monotonic() - started
    # What the gateway checked (a scrypt each) and what it refused unchecked, per address.
    checked: Counter[str] = Counter()
    unchecked: Counter[str] = Counter()
    pattern = re.compile(r"^(HTTP|OPC UA|FTP): login as '[^']*' from (\S+) refused (unchecked|\()")
    for record in records.records:
        match = pattern.match(record.getMessage()) if record.name == "gateway.auth" else None
        if match:
            (unchecked if match[3] == "unchecked" else checked)[match[2]] += 1
    guessers = [*sources, "127.0.0.1"]
    assert {a: checked[a] for a in guessers} == dict.fromkeys(guessers, failures), checked
    # A clean address still gets in.
    assert await http_login(url, USERS["otto"][1], "127.0.3.1")
    assert await ftp_login(port, PASSWORD, "127.0.3.1")
    return {
        "guessing_addresses": len(guessers),
        "guesses_each": guesses,
        "checked_per_address": max(checked[a] for a in guessers),
        "refused_unchecked": sum(unchecked[a] for a in guessers),
        "guessing_s": round(seconds, 1),
    }


@pytest.mark.timeout(900)
async def test_an_attacker_on_the_network_gets_nothing_to_the_machine(
    tmp_path: Path, records: Records, drill_report: Report
) -> None:
    http_port = free_port()
    url = f"http://127.0.0.1:{http_port}"
    settings = {
        "access": {"lockout": LOCKOUT},
        "http": {"host": "127.0.0.1", "port": http_port},
        "inbox": INBOX,
    }
    jobs = {"auto": None}  # delivered, not started: the drill looks at what reaches the program store
    theirs: set[str] = set()
    async with secure_gateway(tmp_path, gateway=settings, jobs=jobs) as rig:
        await wait_until(lambda: rig.machine.status.is_connected, timeout=20, message="the simulator")
        figures = await passive_races(rig, count("ftp_races"), theirs)
        figures |= await held_slots(rig, count("held_addresses"))
        inbox = rig.gateway.jobs.inbox  # type: ignore[union-attr]
        queue = rig.gateway.jobs.queue  # type: ignore[union-attr]
        corpus = await runners.run_ftp_attacks(inbox, queue, runners.load("ftp/attacks.yaml"))
        failed = [str(o) for o in corpus if not o.ok]
        assert not failed, "attacks without their answer:\n" + "\n".join(failed)
        for case in runners.load("ftp/attacks.yaml"):
            if case["kind"] == "race":
                theirs.add(hashlib.sha256(program(f"attacker {case['name']}")).hexdigest())
        figures |= await guessing(rig, url, count("guessing_addresses"), records)

        jobs_made = queue.list(limit=100_000)
        attacker_jobs = [j.id for j in jobs_made if j.sha256 in theirs]
        on_machine = [name for name, data in store_files(rig).items()
                      if hashlib.sha256(data).hexdigest() in theirs or b"(attacker" in data]  # fmt: skip
        errors = [r for r in records.records if r.levelno >= logging.ERROR or r.exc_info]
        refusals = " ".join(f"{k.replace(' ', '_')}:{v}" for k, v in sorted(inbox.refusals.items()))
        drill_report(
            "ftp security", **figures, corpus_attacks=len(corpus) - 1, jobs=len(jobs_made),
            attacker_jobs=len(attacker_jobs), attacker_programs_on_machine=len(on_machine),
            error_log_lines=len(errors), refusals=refusals,
        )  # fmt: skip
        assert not attacker_jobs and not on_machine
        assert not errors, "errors in the log:\n" + "\n".join(
            f"{r.name}: {r.getMessage()}" for r in errors[:20]
        )

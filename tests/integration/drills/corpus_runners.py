"""Throwing each kind of corpus input at the gateway through its real interface, and reading the answer.

Every runner returns `Outcome`s rather than asserting, so that one run reports
every input that did not get its clear error, not only the first.
"""

from __future__ import annotations

import asyncio
import ftplib
import hashlib
import io
import json
import logging
import os
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from gateway.config.validation import ValidationRules
from gateway.errors import ConfigError
from gateway.jobs.inbox.inbox import Inbox
from gateway.jobs.queue.store import JobState
from gateway.jobs.validation.pipeline import validate_program
from tests import ftp_attacks as attacks
from tests.ftp_attacks import Race
from tests.integration.drills.corpus_rig import MACHINE, CorpusRig
from tests.integration.drills.processes import BIN, ROOT, clean_env
from tests.integration.jobs.conftest import PASSWORD, USER, in_thread, inbox_stor, program
from tests.integration.mqtt.conftest import Recorder
from tests.unit.config.test_corpus import CASES as MAPPING_CASES
from tests.unit.config.test_corpus import expectations
from tests.unit.jobs.validation.test_validation import CASES as GCODE_CASES
from tests.unit.jobs.validation.test_validation import header
from tests.waiting import wait_until

CORPUS = ROOT / "tests" / "corpus"


@dataclass
class Outcome:
    kind: str
    name: str
    ok: bool
    detail: str = ""

    def __str__(self) -> str:
        return f"{self.kind}: {self.name}: {self.detail}"


def load(relative: str) -> list[dict[str, Any]]:
    cases = yaml.safe_load((CORPUS / relative).read_text(encoding="utf-8"))
    assert isinstance(cases, list), relative
    for case in cases:
        assert isinstance(case.get("name"), str) and "expect" in case, f"{relative}: {case}"
    return cases


# --- mapping files: the loader, and `cnc-gateway check` -----------------------------------------------


def run_mappings() -> list[Outcome]:
    out = []
    for path in MAPPING_CASES:
        from gateway.config.loader import load_mapping

        try:
            load_mapping(path, environ={})
        except ConfigError as exc:
            missing = [
                f"{line} {key} | {fragment}"
                for line, key, fragment in expectations(path)
                if not any(i.line == line and i.key == key and fragment in i.message for i in exc.issues)
            ]
            out.append(Outcome("mapping", path.name, not missing, f"missing {missing}; got {exc}"))
        else:
            out.append(Outcome("mapping", path.name, False, "loaded without an error"))
    # The same files through the command line, in one process: every located error on stderr, exit 2.
    env = {k: v for k, v in clean_env().items() if not k.startswith(("LASER_SIM_", "CNC_"))}
    proc = subprocess.run([str(BIN / "cnc-gateway"), "check", *map(str, MAPPING_CASES)], capture_output=True,
                          text=True, timeout=120, env=env, check=False)  # fmt: skip
    lost = [f"{p.name}:{line}: {key}" for p in MAPPING_CASES for line, key, _ in expectations(p)
            if (f"{p}:{line}: {key}:" if key else f"{p}:{line}: ") not in proc.stderr]  # fmt: skip
    good = (
        proc.returncode == 2
        and not lost
        and "Traceback" not in proc.stderr
        and "nothing was started" in proc.stderr
    )
    out.append(
        Outcome("mapping", "cnc-gateway check (all files)", good, f"exit {proc.returncode}, missing {lost}")
    )
    return out


# --- G-code jobs through the FTP inbox ----------------------------------------------------------------


def gcode_cases() -> list[tuple[Path, list[str], dict[str, Any], str]]:
    return [(path, *header(path)) for path in GCODE_CASES]


def stor(port: int, machine: str, name: str, data: bytes) -> str:
    return inbox_stor(port, machine, name, data, timeout=30)


async def run_gcode(rig: CorpusRig) -> list[Outcome]:
    """Each file to the machine with its rules; rejected ones carry every expected rule in their reason."""
    out = []
    waiting = []
    for path, expect, rules, name in gcode_cases():
        machine = rig.machine_for(rules)
        data = path.read_bytes()
        reply = await in_thread(stor, rig.inbox_port, machine, name, data)
        verdict = validate_program(data, name, ValidationRules.model_validate(rules))
        accepted = expect == ["accepted"]
        if verdict.accepted != accepted or not reply.startswith("226 J" if accepted else "550 J"):
            out.append(Outcome("gcode", path.name, False, f"reply {reply!r}"))
            continue
        waiting.append((int(reply.split()[1][1:]), path.name, machine, name, expect, verdict))
    for seq, file, machine, name, expect, verdict in waiting:
        job = rig.queue.get(seq)
        if expect == ["accepted"]:
            try:
                await wait_until(lambda s=seq: rig.queue.get(s).state is JobState.DELIVERED, timeout=20)
            except AssertionError:
                out.append(Outcome("gcode", file, False, f"valid job not delivered: {rig.queue.get(seq)}"))
                continue
            arrived = (rig.store / "DATA" / machine / name).read_bytes()
            out.append(Outcome("gcode", file, arrived == verdict.program, "delivered, valid control"))
            continue
        reason_file = rig.state / "rejected" / f"{job.id}-{name}.reason"
        reason = reason_file.read_text() if reason_file.exists() else ""
        missing = [rule for rule in {e.split()[0] for e in expect} if f"[{rule}]" not in reason]
        there = rig.store / "DATA" / machine / name
        leaked = there.exists() and there.read_bytes() == (CORPUS / "gcode" / file).read_bytes()
        ok = job.state is JobState.REJECTED and not missing and not leaked
        out.append(
            Outcome(
                "gcode", file, ok, f"{job.state.value}, missing rules {missing}, reached controller {leaked}"
            )
        )
    return out


# --- MQTT /set and command requests -----------------------------------------------------------------


def payload(case: dict[str, Any]) -> bytes:
    if "payload_hex" in case:
        return bytes.fromhex(case["payload_hex"].split("#")[0].replace(" ", ""))
    if "parts" in case:
        return "".join(p["text"] * p.get("times", 1) for p in case["parts"]).encode()
    return str(case["payload"]).encode("utf-8")


async def publish_retained(rec: Recorder, cases: list[dict[str, Any]]) -> None:
    """Leave the retained requests on the broker, before the gateway connects and subscribes.

    `rec` subscribes to them too: their echo says the broker has them.
    """
    for case in cases:
        if case.get("retain"):
            rec.publish(case["topic"], payload(case), qos=1, retain=True)
            await wait_until(
                lambda t=case["topic"]: rec.on(t), timeout=10, message=f"{case['name']} on the broker"
            )


async def run_mqtt(rec: Recorder, kind: str, cases: list[dict[str, Any]]) -> list[Outcome]:
    """Each request from a real paho client; its answer on `<topic>/result` must refuse it, with the status.

    Retained requests were published before the gateway subscribed (`publish_retained`): the broker replays
    them to it then, and their answers are already there or on their way. They are judged first, so that
    the first answer on their topic is theirs and no later request takes it for its own.
    """
    out = []
    for case in sorted(cases, key=lambda c: not c.get("retain")):
        topic, expect = case["topic"], case["expect"]
        answer_topic = f"{topic}/result"
        before = 0 if case.get("retain") else len(rec.on(answer_topic))
        if not case.get("retain"):
            rec.publish(topic, payload(case), qos=1)
        try:
            await wait_until(
                lambda t=answer_topic, n=before: len(rec.on(t)) > n, timeout=10, message=case["name"]
            )
        except AssertionError:
            out.append(Outcome(kind, case["name"], False, f"no answer on {answer_topic}"))
            continue
        doc = rec.on(answer_topic)[before].json()
        ok = (
            doc.get("ok") is False
            and doc.get("status") == expect["status"]
            and expect["error"] in doc.get("error", "")
        )
        out.append(Outcome(kind, case["name"], ok, json.dumps(doc)[:300]))
    return out


# --- Sparkplug NCMD and DCMD ---------------------------------------------------------------------------


def sparkplug_payload(case: dict[str, Any]) -> bytes:
    if "parts" in case:
        return b"".join(bytes.fromhex(part["hex"]) * part.get("times", 1) for part in case["parts"])
    return bytes.fromhex(str(case["hex"]))


async def run_sparkplug(rig: CorpusRig, rec: Recorder, cases: list[dict[str, Any]]) -> list[Outcome]:
    """Each NCMD/DCMD from a real paho client to the gateway's edge node: refused, counted by its kind.

    The corpus names the aliases of its own births; they are translated to the ones the edge node bound.
    """
    from gateway.sinks.sparkplug.sink import SparkplugSink
    from tests.integration.drills.corpus_rig import SPARKPLUG_MACHINE
    from tests.integration.sparkplug.test_corpus import DEVICE_ALIASES, translated

    sink = rig.gateway.sink("sparkplug", SparkplugSink)
    device = sink.devices[SPARKPLUG_MACHINE]
    assert sink.node is not None and sink.requests is not None
    aliases = {corpus: device.by_name[name] for corpus, name in DEVICE_ALIASES.items()}
    aliases[1] = next(m.alias for m in sink.node.metrics if m.name == "Gateway/Version")
    refusals = sink.requests.refusals
    out = []
    for case in cases:
        kind = case["expect"]["kind"]
        before = dict(refusals)
        topic = f"spBv1.0/{sink.group_id}/{case['message']}/{sink.edge_node_id}"
        if case["message"] == "DCMD":
            topic += f"/{SPARKPLUG_MACHINE}"
        data = sparkplug_payload(case)
        rec.publish(topic, translated(data, aliases), qos=0)
        try:
            await wait_until(lambda b=before: sum(refusals.values()) > sum(b.values()), timeout=10,
                             message=case["name"])  # fmt: skip
        except AssertionError:
            out.append(Outcome("sparkplug", case["name"], False, "not refused"))
            continue
        counted = {k: n - before.get(k, 0) for k, n in refusals.items() if n != before.get(k, 0)}
        out.append(
            Outcome("sparkplug", case["name"], counted == {kind: 1}, f"counted {counted}, expected {kind}")
        )
    return out


# --- FTP paths and names -----------------------------------------------------------------------------


def ftp_case(port: int, case: dict[str, Any], program: bytes) -> list[str]:
    """Run the case's commands in one session; the replies (an error's text for a refusal)."""
    ftp = ftplib.FTP(encoding="utf-8")
    ftp.connect("127.0.0.1", port, timeout=30)
    replies = []
    try:
        ftp.login(USER, PASSWORD)
        ftp.cwd(case.get("cwd", f"/{MACHINE}"))
        for command in case["commands"]:
            verb = command.split(" ", 1)[0].upper()
            if verb not in ("STOR", "STOU", "APPE", "RETR"):
                replies.append(attacks.reply(ftp, command))
                continue
            try:
                if verb == "RETR":
                    replies.append(ftp.retrbinary(command, lambda _: None))
                else:
                    replies.append(ftp.storbinary(command, io.BytesIO(program)))
            except ftplib.Error as exc:
                replies.append(str(exc))
    finally:
        ftp.close()
    return replies


async def run_ftp(
    rig: CorpusRig, cases: list[dict[str, Any]], program: bytes, outside: Path
) -> list[Outcome]:
    out = []
    for case in cases:
        if "symlink" in case:
            os.symlink(outside, rig.state / "inbox" / MACHINE / case["symlink"])
        replies = await in_thread(ftp_case, rig.inbox_port, case, program)
        *steps, last = replies
        code, fragment = case["expect"]["code"], case["expect"]["fragment"]
        ok = all(r[:1] in "123" for r in steps) and last.startswith(code) and fragment in last
        out.append(Outcome("ftp", case["name"], ok, " | ".join(replies)[:300]))
    # Nothing got out: no file by those names outside the inbox's own folders (temporary uploads) and the
    # rejected/ folder, no job for them delivered, and the file behind the symbolic link untouched.
    base = rig.state.parent
    inside = (rig.state / "inbox", rig.state / "rejected")
    stray = [str(p) for p in base.rglob("*escape*") if not any(p.is_relative_to(d) for d in inside)]
    delivered = [j.filename for j in rig.queue.list(limit=10_000)
                 if "escape" in j.filename and j.state is not JobState.REJECTED]  # fmt: skip
    kept_out = not stray and not delivered and outside.read_bytes() == program
    out.append(Outcome("ftp", "nothing escaped", kept_out, f"stray files {stray}, jobs {delivered}"))
    return out


# --- attacks on the inbox's sessions and data connections (tests/corpus/ftp/attacks.yaml) ---------------


NO_ATTACKER_JOB = "no job of an attacker's program"  # the summary outcome of run_ftp_attacks


def filler(size: int) -> bytes:
    """`size` bytes of G-code lines, for appends."""
    line = b"G1 X1 Y1 F1200\n"
    return (line * (size // len(line) + 1))[:size]


def _append(ftp: ftplib.FTP, name: str, data: bytes) -> str:
    try:
        return ftp.storbinary(f"APPE {name}", io.BytesIO(data))
    except ftplib.Error as exc:
        return str(exc)
    except OSError:  # the server cut the data connection: its reason follows on the control connection
        try:
            return ftp.getresp()
        except ftplib.Error as exc:
            return str(exc)


def attack_race(port: int, case: dict[str, Any], victim: bytes, attacker: bytes) -> Race:
    ftp = attacks.login(port, USER, PASSWORD)
    try:
        ftp.cwd(f"/{MACHINE}")
        return attacks.race_stor(ftp, case["file"], victim, attacker, verb=case.get("verb", "PASV"),
                                 victim_connects=case.get("victim_connects", True),
                                 attacker_source=case["attacker"])  # fmt: skip
    finally:
        ftp.close()


def attack_before_login(port: int, case: dict[str, Any]) -> list[str]:
    ftp = attacks.connect(port, source=case["source"])
    try:
        return [attacks.reply(ftp, command) for command in case["commands"]]
    finally:
        ftp.close()


def attack_hold(
    port: int, case: dict[str, Any], cap: int, login_timeout: float
) -> tuple[list[str], list[str]]:
    """(the refusals of the sessions past the cap, how each held session ended)"""
    held, refused = attacks.open_sessions(port, cap + case["extra"], source=case["source"])
    try:
        ends = attacks.noop_until_closed(held, login_timeout + 20)
        return refused, [e.text if e is not None else "still open" for e in ends]
    finally:
        for ftp in held:
            ftp.close()


def attack_guess(port: int, case: dict[str, Any], failures: int) -> tuple[list[str], list[str]]:
    """(the answers to the wrong passwords, the answers to two right ones after them)"""
    user = USER if case["user"] == "account" else case["user"]
    guesses: list[str] = []
    while len(guesses) < failures:
        ftp = attacks.connect(port, source=case["source"])
        try:
            for _ in range(min(3, failures - len(guesses))):  # the inbox ends a session after 3 failures
                try:
                    ftp.login(user, f"guess-{len(guesses)}")
                    guesses.append("230 logged in")
                except ftplib.Error as exc:
                    guesses.append(str(exc))
        finally:
            ftp.close()
    right = []
    for _ in range(2):
        try:
            attacks.login(port, USER, PASSWORD, source=case["source"]).close()
            right.append("230 logged in")
        except ftplib.Error as exc:
            right.append(str(exc))
    return guesses, right


def attack_appe(port: int, case: dict[str, Any], limit: int) -> tuple[list[str], list[int]]:
    """(each APPE's answer, the file's size after each)"""
    ftp = attacks.login(port, USER, PASSWORD)
    replies, sizes = [], []
    try:
        ftp.cwd(f"/{MACHINE}")
        for fraction in case["sizes"]:
            replies.append(_append(ftp, case["file"], filler(int(fraction * limit))))
            sizes.append(ftp.size(case["file"]) or 0)
    finally:
        ftp.close()
    return replies, sizes


def _matches(reply: str, expect: dict[str, Any]) -> bool:
    return reply.startswith(expect["code"]) and expect.get("fragment", "") in reply


async def run_ftp_attacks(inbox: Inbox, queue: Any, cases: list[dict[str, Any]]) -> list[Outcome]:
    """Each attack against the running `inbox` (jobs in `queue`); the last outcome: no job ever held an
    attacker's program."""
    out = []
    config = inbox.config
    limit, cap = int(config.max_file_size), config.max_connections_per_address
    theirs: set[str] = set()
    for case in cases:
        kind, expect = case["kind"], case["expect"]
        if kind == "race":
            victim, attacker = program(f"victim {case['name']}"), program(f"attacker {case['name']}")
            theirs.add(hashlib.sha256(attacker).hexdigest())
            before = inbox.refusals["foreign data connection"]
            race = await in_thread(attack_race, inbox.port, case, victim, attacker)
            ok = _matches(race.final, expect) and inbox.refusals["foreign data connection"] == before + 1
            if ok and race.final.startswith("226 J"):
                job = queue.get(int(race.final.split()[1][1:]))
                ok = job.sha256 == hashlib.sha256(victim).hexdigest() and job.user == USER
            out.append(Outcome("ftp-attack", case["name"], ok, f"{race}"[:300]))
        elif kind == "before-login":
            replies = await in_thread(attack_before_login, inbox.port, case)
            wrong = [r for r in replies if not _matches(r, expect)]
            out.append(
                Outcome("ftp-attack", case["name"], not wrong, f"not refused as expected: {wrong}"[:300])
            )
        elif kind == "hold":
            refused, ends = await in_thread(attack_hold, inbox.port, case, cap, config.login_timeout)
            ok = (len(refused) == case["extra"] and all(_matches(r, expect) for r in refused)
                  and len(ends) == cap and all("not logged in within" in e for e in ends))  # fmt: skip
            out.append(Outcome("ftp-attack", case["name"], ok, f"refused {refused}, held ended {ends}"[:300]))
        elif kind == "guess":
            guesses, right = await in_thread(attack_guess, inbox.port, case, inbox.logins.failures)
            ok = all(g.startswith("530 login incorrect") for g in guesses) and all(
                _matches(r, expect) for r in right
            )
            out.append(Outcome("ftp-attack", case["name"], ok, f"guesses {guesses}, then {right}"[:300]))
        elif kind == "appe":
            replies, sizes = await in_thread(attack_appe, inbox.port, case, limit)
            kept = sum(
                int(f * limit) for f, r in zip(case["sizes"], replies, strict=True) if r.startswith("226")
            )
            ok = ([r[:3] for r in replies] == expect["codes"] and max(sizes) <= limit
                  and sizes[-1] == kept)  # fmt: skip
            out.append(Outcome("ftp-attack", case["name"], ok, f"replies {replies}, sizes {sizes}"[:300]))
        else:
            out.append(Outcome("ftp-attack", case["name"], False, f"unknown kind {kind!r}"))
    leaked = [j.id for j in queue.list(limit=10_000) if j.sha256 in theirs]
    out.append(Outcome("ftp-attack", NO_ATTACKER_JOB, not leaked, f"jobs {leaked}"))
    return out


# --- COPYDATA frames --------------------------------------------------------------------------------


async def copydata_case(port: int, data: bytes, expect: dict[str, Any], feedback: Recorder,
                        records: list[logging.LogRecord]) -> tuple[bool, str]:  # fmt: skip
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    peer = f"127.0.0.1:{writer.get_extra_info('sockname')[1]}"

    async def drain() -> None:  # the target's own frames (a snapshot first), until it closes
        try:
            while await reader.read(65536):
                pass
        except ConnectionError:
            pass

    reading = asyncio.create_task(drain(), name="corpus:copydata-read")
    try:
        writer.write(data)
        await writer.drain()
        if "closed" in expect:
            writer.write_eof()
            await asyncio.wait_for(asyncio.shield(reading), 10)
            wanted = f"closing the connection from {peer}: malformed frame ({expect['closed']})"
            await wait_until(
                lambda: any(wanted in r.getMessage() for r in records), timeout=5, message=wanted
            )
            return True, wanted

        def mine() -> dict[str, Any] | None:
            docs = [m.json() for m in feedback.on(f"cnc/{MACHINE}/copydata/feedback")]
            return next((d for d in docs if d.get("peer") == peer), None)

        doc = await wait_until(mine, timeout=10, message=f"feedback for {peer}")
        items = doc["items"]
        wanted_items = expect["items"]
        ok = len(items) == len(wanted_items) and all(
            item.get("write", {}).get("ok") is False
            and item["write"].get("status") == want["status"]
            and want["error"] in item["write"].get("error", "")
            for item, want in zip(items, wanted_items, strict=True)
        )
        return ok, json.dumps(items)[:300]
    except (AssertionError, TimeoutError) as exc:
        return False, str(exc)[:300]
    finally:
        writer.close()
        reading.cancel()
        await asyncio.gather(reading, return_exceptions=True)


async def run_copydata(rig: CorpusRig, cases: list[dict[str, Any]], feedback: Recorder,
                       records: list[logging.LogRecord]) -> list[Outcome]:  # fmt: skip
    port = await rig.copydata_port()
    rig.emitter().throttle.burst = 1_000_000  # every malformed stream's reason in the log, for this check
    out = []
    for case in cases:
        data = bytes.fromhex(case["hex"].replace(" ", ""))
        ok, detail = await copydata_case(port, data, case["expect"], feedback, records)
        out.append(Outcome("copydata", case["name"], ok, detail))
    return out

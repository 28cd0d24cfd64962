"""Drill: the HTTP faces attacked as issue 23 found them open; every other door keeps answering.

A gateway process (its open-file limit at 1,024, the usual default) with every face a shop runs: OPC UA,
MQTT (a real Mosquitto), the web console and REST API, the MTConnect agent and the FTP inbox, over the
simulator (a process too). Then, for `SECONDS` (20 s; 60 s in soak):

- N slow connections (1,000 in soak) on each HTTP face (slow_http.Siege: silent ones, slow-loris header
  drips, and on the web face slow multipart uploads), half from one address and half spread over twenty,
  each opened again a second after the server closes it;
- meanwhile the other doors are probed from another address, again and again: an OPC UA read on a fresh
  session, `/healthz`, an MTConnect `/current`, an FTP login, an MQTT write's round trip
  (`…/set` to `…/set/result`). Each probe's worst latency is reported (the issue's target: within 1 s);
  the drill fails only when a probe gets no answer within 10 s (slow_http.LIMIT);
- uploads whose bodies are held back (tests/corpus/http/spooling.yaml) must be answered before their body
  is in, with nothing written to the inbox's staging folder;
- every `next` of tests/corpus/http/redirects.yaml given to a login must send the browser to this host.

The same probes are first measured on the quiet gateway, for comparison. The report also gives the most
descriptors the gateway held (from /proc) and how many times its log says `Too many open files`.
"""

from __future__ import annotations

import asyncio
import contextlib
import ftplib
import os
import time
from pathlib import Path
from typing import Any

import aiohttp
import pytest
import yaml
from yarl import URL

from gateway.auth.passwords import hash_password
from tests.integration.drills import processes
from tests.integration.drills.conftest import SCALE, Report, count
from tests.integration.drills.corpus_rig import MACHINE, laser_sim_mapping
from tests.integration.drills.slow_http import (
    LIMIT,
    Probe,
    SiegeProcess,
    Target,
    count_files,
    cpu_seconds,
    held_upload,
    lands_on,
    run_probes,
)
from tests.integration.jobs.conftest import PASSWORD, PASSWORD_HASH, USER, in_thread
from tests.integration.mqtt.conftest import Mosquitto, Recorder, subscriber
from tests.opcua_client import Client
from tests.waiting import free_port, wait_until

SLOW = count("slow_connections")  # per HTTP face
SECONDS = 60.0 if SCALE == "soak" else 20.0
QUIET = 5.0  # s of probing before the siege
RAMP = 20.0  # s at most for the slow connections to open before the probing starts
NOFILE = 1024  # the gateway's open-file limit (soft and hard)
CORPUS = Path(__file__).resolve().parents[2] / "corpus" / "http"
USERS = {
    "otto": ("operator", "otto-secret"),
    "vera": ("viewer", "vera-secret"),
    "ada": ("admin", "ada-secret"),
}


def gateway_file(directory: Path, ports: dict[str, int], mqtt_port: int) -> Path:
    processes.write_yaml(directory / f"{MACHINE}.yaml", laser_sim_mapping(ports["sim"], ports["sim_ftp"]))
    return processes.write_yaml(
        directory / "gateway.yaml",
        {
            "opcua": {"endpoint": f"opc.tcp://127.0.0.1:{ports['opcua']}/cnc-gateway", "security": ["None"]},
            "state_dir": "state",
            "log_level": "info",
            "machines": [f"{MACHINE}.yaml"],
            "inbox": {"host": "127.0.0.1", "port": ports["inbox"],
                      "accounts": [{"user": USER, "password_hash": PASSWORD_HASH}]},
            "mqtt": {"host": "127.0.0.1", "port": mqtt_port, "client_id": "drill-gateway"},
            "http": {"host": "127.0.0.1", "port": ports["http"]},
            "mtconnect": {"host": "127.0.0.1", "port": ports["mtconnect"]},
            "users": [{"name": name, "role": role, "password_hash": hash_password(password, n=2**10)}
                      for name, (role, password) in USERS.items()],
            # The mapping's COPYDATA target takes writes: they act as the operator (the loader refuses it
            # otherwise; no door acts as the admin for want of a login).
            "access": {"mqtt_writer_role": "operator", "copydata_role": "operator"},
        },
    )  # fmt: skip


def limited(process: processes.Process) -> processes.Process:
    """The process with its open-file limit at NOFILE, as a service manager would start it."""
    process.argv = ["sh", "-c", f'ulimit -n {NOFILE} && exec "$@"', "sh", *process.argv]
    return process


def descriptors(pid: int) -> int:
    try:
        return len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return 0


def ftp_login(port: int) -> None:
    ftp = ftplib.FTP()
    ftp.connect("127.0.0.1", port, timeout=LIMIT)
    try:
        ftp.login(USER, PASSWORD)
        ftp.quit()
    finally:
        ftp.close()


async def login(url: str, user: str, next_url: str = "/") -> tuple[aiohttp.ClientSession, str]:
    """A console session for `user`: the client (its cookie) and the Location the login answered with."""
    session = aiohttp.ClientSession(base_url=url, cookie_jar=aiohttp.CookieJar(unsafe=True))
    async with session.post(
        "/login", data={"username": user, "password": USERS[user][1], "next": next_url}, allow_redirects=False
    ) as r:
        assert r.status == 303, await r.text()
        location = r.headers["Location"]
    return session, location


async def session_headers(session: aiohttp.ClientSession, url: str, csrf: bool = True) -> dict[str, str]:
    """A session's cookie (and CSRF token) as raw headers, for requests written on a bare socket."""
    cookies = session.cookie_jar.filter_cookies(URL(url))
    headers = {"Cookie": "; ".join(f"{k}={v.value}" for k, v in cookies.items())}
    if csrf:
        async with session.get("/") as r:
            text = await r.text()
        marker = '<meta name="csrf" content="'
        start = text.index(marker) + len(marker)
        headers["X-CSRF-Token"] = text[start : text.index('"', start)]
    return headers


@pytest.mark.timeout(240 + SECONDS * 2)
async def test_slow_connections_on_the_http_faces_leave_every_other_door_answering(
    mosquitto: Mosquitto, recorders: list[Recorder], tmp_path: Path, drill_report: Report
) -> None:
    ports = {k: free_port() for k in ("sim", "sim_ftp", "opcua", "inbox", "http", "mtconnect")}
    sim = processes.simulator(tmp_path, ports["sim"], ports["sim_ftp"])
    gateway = limited(processes.gateway(tmp_path, gateway_file(tmp_path, ports, mosquitto.port)))
    web = f"http://127.0.0.1:{ports['http']}"
    agent = f"http://127.0.0.1:{ports['mtconnect']}"
    staging = tmp_path / "state" / "inbox" / ".staging"
    mqtt = subscriber(recorders, mosquitto.port, topics=[f"cnc/{MACHINE}/#"])
    siege = SiegeProcess(
        [Target("web", ports["http"], SLOW, "/api/jobs"), Target("mtconnect", ports["mtconnect"], SLOW)]
    )
    sessions: list[aiohttp.ClientSession] = []
    peak_fds = 0
    try:
        await asyncio.to_thread(sim.start)
        await asyncio.to_thread(processes.wait_for_port, sim, ports["sim"])
        await asyncio.to_thread(gateway.start)
        for face in ("http", "mtconnect", "inbox", "opcua"):
            await asyncio.to_thread(processes.wait_for_port, gateway, ports[face])
        async with Client(f"opc.tcp://127.0.0.1:{ports['opcua']}/cnc-gateway", timeout=LIMIT) as client:
            node = client.get_node(f"ns=2;s={MACHINE}/Status/Connected")
            await wait_until(node.read_value, timeout=30, message="the gateway connected to the simulator")

        probes = make_probes(ports, web, agent, mqtt)
        await run_probes(probes, QUIET)
        quiet = {p.name: p.figure() for p in probes}
        assert not any(p.failures for p in probes), {p.name: p.failures[:3] for p in probes}

        siege.start()
        with contextlib.suppress(AssertionError):  # a gateway out of descriptors never lets them all in
            await wait_until(lambda: min(siege.opened()) >= SLOW, timeout=RAMP, interval=0.2)
        ramp = siege.opened()

        async def watch_fds() -> None:
            nonlocal peak_fds
            while True:
                peak_fds = max(peak_fds, descriptors(gateway.pid))
                await asyncio.sleep(0.25)

        watcher = asyncio.create_task(watch_fds())
        cpu_before, started = cpu_seconds(gateway.pid), time.monotonic()
        probes = make_probes(ports, web, agent, mqtt)
        probing = asyncio.create_task(run_probes(probes, SECONDS))
        held: dict[str, tuple[Any, str]] = {}
        redirects: dict[str, str] = {}
        errors = []  # logins that failed under the siege
        try:
            otto, _ = await login(web, "otto")
            sessions.append(otto)
            held = await held_uploads(ports["http"], web, staging, otto)
            redirects = await redirect_checks(web)
        except (aiohttp.ClientError, TimeoutError, AssertionError) as exc:
            errors.append(f"{type(exc).__name__}: {exc}")
        await probing
        watcher.cancel()
        gateway_cpu = (cpu_seconds(gateway.pid) - cpu_before) / (time.monotonic() - started)
        stats = siege.stop()
        alive = gateway.alive
        too_many = gateway.tail(10_000_000).count("Too many open files")
        staged_after = count_files(staging)
    finally:
        try:
            siege.stop()
            for session in sessions:
                await session.close()
        finally:  # the processes go whatever happened above
            await asyncio.to_thread(gateway.stop)
            await asyncio.to_thread(sim.stop)

    bad_held = [f"{name}: {h}" for name, (h, want) in held.items() if h.status != want or h.staged]
    left = [f"{name}: {host}" for name, host in redirects.items() if host != f"127.0.0.1:{ports['http']}"]
    drill_report(
        "slow connections on the HTTP faces", per_face=SLOW, seconds=SECONDS, gateway_nofile=NOFILE,
        **{f"quiet_{k}": v for k, v in quiet.items()},
        **{f"siege_{p.name}": p.figure() for p in probes},
        opened_in_ramp=ramp, **{f"{face}_{k}": v for face, got in stats.items() for k, v in got.items()},
        gateway_peak_fds=peak_fds, too_many_open_files=too_many, gateway_cpu=f"{gateway_cpu:.0%} of a core",
        load_average=" ".join(f"{x:.2f}" for x in os.getloadavg()),
        held_uploads=", ".join(f"{h.status or 'no answer'} in {h.seconds:.2f}s/{h.staged} staged"
                               for h, _ in held.values()),
        redirects=len(redirects), redirects_off_host=len(left), login_errors=len(errors),
    )  # fmt: skip
    assert alive, "the gateway stopped"
    assert not errors, f"the console's login failed under the siege: {errors}"
    failed = {p.name: p.failures[:3] for p in probes if p.failures}
    assert not failed, f"doors that did not answer within {LIMIT} s under the siege: {failed}"
    assert not bad_held, "uploads answered late, wrongly or spooled:\n" + "\n".join(bad_held)
    assert staged_after == 0
    assert not left, "logins that sent the browser elsewhere:\n" + "\n".join(left)


def make_probes(ports: dict[str, int], web: str, agent: str, mqtt: Recorder) -> list[Probe]:
    async def opcua() -> None:
        async with Client(f"opc.tcp://127.0.0.1:{ports['opcua']}/cnc-gateway", timeout=LIMIT) as client:
            await client.get_node(f"ns=2;s={MACHINE}/Machine/State").read_value()

    async def get(url: str) -> None:
        connector = aiohttp.TCPConnector(force_close=True)
        async with aiohttp.ClientSession(connector=connector) as session, session.get(url) as r:
            assert r.status == 200, r.status
            await r.read()

    async def ftp() -> None:
        await in_thread(ftp_login, ports["inbox"])

    topic = f"cnc/{MACHINE}/feed/override"
    values = iter(range(1_000_000))

    async def mqtt_write() -> None:
        value = 50 + next(values) % 50
        before = len(mqtt.on(f"{topic}/set/result"))
        mqtt.publish(f"{topic}/set", str(value).encode())
        await wait_until(lambda: len(mqtt.on(f"{topic}/set/result")) > before, timeout=LIMIT, interval=0.005,
                         message="the write's answer")  # fmt: skip
        answer = mqtt.on(f"{topic}/set/result")[before].json()
        assert answer == {"ok": True}, answer

    return [
        Probe("opcua_read", opcua),
        Probe("healthz", lambda: get(f"{web}/healthz")),
        Probe("mtconnect_current", lambda: get(f"{agent}/current")),
        Probe("ftp_login", ftp),
        Probe("mqtt_round_trip", mqtt_write),
    ]


async def held_uploads(
    port: int, web: str, staging: Path, otto: aiohttp.ClientSession
) -> dict[str, tuple[Any, str]]:
    """Each case of spooling.yaml (anonymous visitors are viewers here): what the gateway answered."""
    vera, _ = await login(web, "vera")
    try:
        auth = {
            "anonymous": {},
            "otto": await session_headers(otto, web),
            "vera": await session_headers(vera, web),
            "bad-token": {"Authorization": "Bearer cgw_00000000_" + "x" * 43},
        }
        out = {}
        for case in yaml.safe_load((CORPUS / "spooling.yaml").read_text(encoding="utf-8")):
            who = case.get("as", "anonymous")
            if who not in auth:
                continue  # API tokens are made by the CLI beside the gateway: the web tests cover them
            headers = dict(auth[who])
            if case.get("csrf") is False:
                headers.pop("X-CSRF-Token", None)
            held = await held_upload(
                port, case["path"], staging, headers=headers, method=case.get("method", "POST")
            )
            out[case["name"]] = (held, str(case["expect"]))
        return out
    finally:
        await vera.close()


async def redirect_checks(web: str) -> dict[str, str]:
    """Each `next` of redirects.yaml given to otto's login: the host a browser would land on."""
    out = {}
    for case in yaml.safe_load((CORPUS / "redirects.yaml").read_text(encoding="utf-8")):
        session, location = await login(web, "otto", case["next"])
        await session.close()  # (kept open, 40 sessions from one address would meet its cap)
        out[case["name"]] = lands_on(web + "/login", location)
    return out

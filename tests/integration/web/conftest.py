"""The web console against a real gateway and simulator: the shipped laser-sim mapping with its jobs and
alarms, users of every role, the OPC UA server with secure endpoints, and the console on a free port.

Browser tests drive Debian's Chromium (/usr/bin/chromium) through Playwright's async API, in the same
event loop as the gateway; Playwright's own browser download is not used (it cannot be fetched here).
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from gateway.app import Gateway
from gateway.auth.passwords import hash_password
from gateway.config.gateway import GatewayConfig
from gateway.config.loader import Config
from gateway.sinks.web.sink import WebSink
from simulator.runner import Simulator
from tests.integration.security.conftest import laser_mapping
from tests.waiting import free_port, wait_until

MACHINE = "laser-sim"
CHROMIUM = "/usr/bin/chromium"
HAVE_CHROMIUM = Path(CHROMIUM).exists()
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-dev-shm-usage",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
# name -> (role, password). Cheap scrypt parameters: the tests log in many times.
USERS = {
    "vera": ("viewer", "vera-secret"),
    "otto": ("operator", "otto-secret"),
    "erik": ("engineer", "erik-secret"),
    "ada": ("admin", "ada-secret"),
}


@dataclass
class WebRig:
    gateway: Gateway
    sim: Simulator
    url: str
    opcua: str
    state_dir: Path
    sessions: list[aiohttp.ClientSession] = field(default_factory=list)

    @property
    def machine(self) -> Any:
        return self.gateway.tree.machines[MACHINE]

    @property
    def web(self) -> WebSink:
        return self.gateway.sink("web", WebSink)

    async def session(self, user: str | None = None) -> aiohttp.ClientSession:
        """An HTTP client, logged in as `user` (None: anonymous); its CSRF token in `.headers`."""
        session = aiohttp.ClientSession(base_url=self.url, cookie_jar=aiohttp.CookieJar(unsafe=True))
        self.sessions.append(session)
        if user is None:
            return session
        async with session.post(
            "/login", data={"username": user, "password": USERS[user][1], "next": "/"}, allow_redirects=False
        ) as r:
            assert r.status == 303, await r.text()
        session.headers["X-CSRF-Token"] = await self.csrf(session)
        return session

    @staticmethod
    async def csrf(session: aiohttp.ClientSession) -> str:
        async with session.get("/") as r:
            text = await r.text()
        marker = '<meta name="csrf" content="'
        start = text.index(marker) + len(marker)
        return text[start : text.index('"', start)]


def users_config() -> list[dict[str, str]]:
    return [
        {"name": name, "role": role, "password_hash": hash_password(password, n=2**10)}
        for name, (role, password) in USERS.items()
    ]


@asynccontextmanager
async def web_gateway(
    tmp_path: Path, *, speed: float = 20.0, elsewhere: tuple[str, ...] = (), **gateway: Any
) -> AsyncIterator[WebRig]:
    """The gateway with its console over a simulator; `elsewhere`: machines of the fleet that another shard
    serves (with the simulator's jobs section), as `shard:` leaves them in the configuration."""
    sim_port, ftp_port, port, http_port = free_port(), free_port(), free_port(), free_port()
    state = tmp_path / "state"
    settings: dict[str, Any] = {
        "opcua": {"endpoint": f"opc.tcp://127.0.0.1:{port}/cnc-gateway", "profile": "standard"},
        "state_dir": str(state),
        "inbox": {"port": free_port()},
        "users": users_config(),
        "http": {"host": "127.0.0.1", "port": http_port},
    }
    if gateway.get("http") is not None:  # merged (a port given there wins); None: no console
        gateway["http"] = {**settings["http"], **gateway["http"]}
        http_port = gateway["http"]["port"]
    settings.update(gateway)
    mapping = laser_mapping(sim_port, ftp_port)
    assert mapping.jobs is not None
    jobs = mapping.jobs.model_copy(update={"retry": mapping.jobs.retry.model_copy(update={"initial": 0.2})})
    config = Config(
        GatewayConfig.model_validate(settings),
        (mapping.model_copy(update={"jobs": jobs}),),
        tmp_path,
        jobs_elsewhere=dict.fromkeys(elsewhere, jobs),
    )
    async with (
        Simulator(opcua_port=sim_port, ftp_port=ftp_port, speed=speed, store=tmp_path / "store") as sim,
        Gateway(config) as gw,
    ):
        task = asyncio.create_task(gw.run(), name="test:gateway")
        rig = WebRig(
            gw, sim, f"http://127.0.0.1:{http_port}", f"opc.tcp://127.0.0.1:{port}/cnc-gateway", state
        )
        try:
            await wait_until(
                lambda: rig.machine.nodes["Machine/State"].sample.good,
                timeout=20,
                message="the gateway to mirror the simulator",
            )
            yield rig
        finally:
            for session in rig.sessions:
                await session.close()
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)


@pytest.fixture
async def rig(tmp_path: Path) -> AsyncIterator[WebRig]:
    async with web_gateway(tmp_path) as rig:
        yield rig


@pytest.fixture
async def browser() -> AsyncIterator[Any]:
    """Debian's Chromium, headless, through Playwright (skipped where it is not installed)."""
    if not HAVE_CHROMIUM:
        pytest.skip("chromium is not installed (make system-deps installs it)")
    from playwright.async_api import async_playwright

    async with async_playwright() as pw:
        browser = await pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            yield browser
        finally:
            await browser.close()

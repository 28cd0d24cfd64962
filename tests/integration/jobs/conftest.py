"""Real servers for the job queue tests: the simulator's FTP program store, and the gateway's inbox.

`store` is the simulator's FTP program store (simulator.ftp_store) on a free
port; `harness` builds a JobService (inbox + queue + delivery) from a mapping
and an inbox section, the way the gateway does, and runs it.
"""

from __future__ import annotations

import asyncio
import ftplib
import functools
import io
import logging
from collections.abc import AsyncIterator, Callable
from concurrent.futures import ThreadPoolExecutor
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any, TypeVar

import pytest

from gateway.auth.passwords import hash_password
from gateway.config.gateway import GatewayConfig
from gateway.config.jobs import InboxConfig
from gateway.config.loader import Config, load_mapping
from gateway.jobs.queue.store import Job, JobState
from gateway.jobs.service import JobService
from simulator.ftp_store import FtpStore
from simulator.store import DirectoryStore
from tests.trees import MappedTree
from tests.waiting import free_port, wait_until

T = TypeVar("T")

# Blocking FTP clients (ftplib) run here, not in asyncio's small default executor.
CLIENTS = ThreadPoolExecutor(16, thread_name_prefix="test-ftp-client")


async def in_thread(fn: Callable[..., T], *args: Any) -> T:
    return await asyncio.get_running_loop().run_in_executor(CLIENTS, functools.partial(fn, *args))


STORE_USER, STORE_PASSWORD = "cnc", "simulator"
USER, PASSWORD = "nest", "pw-nest"
PASSWORD_HASH = hash_password(PASSWORD, n=2**10)

GOOD = b"%\nO1001 (PART)\nG21 G90\nG0 X10 Y10\nG1 X50 F3000\nG1 Y40\nM30\n%\n"


def program(tag: str, lines: int = 3) -> bytes:
    """A small valid program whose content (and so hash) depends on `tag`."""
    body = "".join(f"G1 X{i + 1} Y{i + 2} F1200\n" for i in range(lines))
    return f"%\n({tag})\nG21 G90\n{body}M30\n%\n".encode()


MAPPING = """
machine: {name}
driver: {{endpoint: "opc.tcp://127.0.0.1:{opcua}"}}
variables:
  - {{path: Machine/State, source: "ns=2;s=::AsGlobalPV:gMachine.State", type: Int16}}
jobs:
  controller: {{host: 127.0.0.1, port: {ftp}, user: cnc, password: simulator, folder: {folder}, timeout: 5}}
  validation: {{dialect: laser-sim}}
  retry: {{initial: 0.05, max: 0.2, factor: 2}}
  max_attempts: {attempts}
{extra}
"""


def mapping_text(
    name: str,
    ftp_port: int,
    *,
    folder: str = "/DATA/Programs",
    attempts: int = 3,
    extra: str = "",
    opcua_port: int = 4999,
) -> str:
    return MAPPING.format(
        name=name, opcua=opcua_port, ftp=ftp_port, folder=folder, attempts=attempts, extra=extra
    )


class Store:
    """The simulator's FTP program store, and what arrived in it."""

    def __init__(self, root: Path, ftp: FtpStore) -> None:
        self.root = root
        self.ftp = ftp
        self.port = ftp.port

    def folder(self, name: str = "Programs") -> Path:
        return self.root / "DATA" / name

    def files(self, name: str = "Programs") -> dict[str, bytes]:
        return {p.name: p.read_bytes() for p in self.folder(name).iterdir() if p.is_file()}


@pytest.fixture
async def store(tmp_path: Path) -> AsyncIterator[Store]:
    root = tmp_path / "controller"
    DirectoryStore(root).prepare()
    (root / "DATA" / "Other").mkdir()
    async with FtpStore(
        root, host="127.0.0.1", port=free_port(), user=STORE_USER, password=STORE_PASSWORD
    ) as ftp:
        yield Store(root, ftp)


class Harness:
    """A running JobService with its tree, state directory and inbox port."""

    def __init__(self, service: JobService, tree: MappedTree, state: Path) -> None:
        self.service = service
        self.tree = tree
        self.state = state

    @property
    def port(self) -> int:
        assert self.service.inbox is not None
        return self.service.inbox.port

    @property
    def queue(self) -> Any:
        return self.service.queue

    def job(self, seq: int) -> Job:
        return self.queue.get(seq)

    def jobs(self) -> list[Job]:
        return self.queue.list(limit=1000, newest_first=False)

    async def wait_state(self, seq: int, *states: JobState, timeout: float = 15.0) -> Job:
        return await wait_until(
            lambda: (j := self.job(seq)).state in states and j,
            timeout=timeout,
            message=f"J{seq:06d} in {'/'.join(s.value for s in states)}",
        )

    def value(self, machine: str, path: str) -> Any:
        return self.tree.machines[machine].nodes[path].sample.value

    def ftp(self, user: str = USER, password: str = PASSWORD) -> ftplib.FTP:
        ftp = ftplib.FTP()
        ftp.connect("127.0.0.1", self.port, timeout=20)
        ftp.login(user, password)
        return ftp

    async def stor(self, machine: str, name: str, data: bytes, **login: str) -> str:
        """Plain STOR with ftplib (in a thread); the gateway's final reply, or the error's text."""
        return await in_thread(lambda: inbox_stor(self.port, machine, name, data, **login))


def inbox_stor(
    port: int,
    machine: str,
    name: str,
    data: bytes,
    *,
    user: str = USER,
    password: str = PASSWORD,
    timeout: float = 20,
) -> str:
    """STOR into /<machine>/ of the inbox at `port`: the final reply, or the refusal's text (blocking: call
    it in a thread). A refused login raises (ftplib.error_perm)."""
    ftp = ftplib.FTP()
    ftp.connect("127.0.0.1", port, timeout=timeout)
    try:
        ftp.login(user, password)
    except BaseException:
        ftp.close()
        raise
    try:
        ftp.cwd(f"/{machine}")
        return ftp.storbinary(f"STOR {name}", io.BytesIO(data))
    except ftplib.Error as exc:
        return str(exc)
    finally:
        ftp.close()


Build = Callable[..., Any]


@pytest.fixture
async def harness(tmp_path: Path) -> AsyncIterator[Build]:
    """`async with harness(mappings, **inbox) as h:` runs a JobService for mapping texts."""

    @asynccontextmanager
    async def build(
        mappings: list[str],
        *,
        environ: dict[str, str] | None = None,
        accounts: Any = None,
        queue: str | None = None,
        **inbox: Any,
    ) -> AsyncIterator[Harness]:
        files = []
        for index, text in enumerate(mappings):
            path = tmp_path / f"machine{index}.yaml"
            path.write_text(text)
            files.append(load_mapping(path, environ={}))
        state = tmp_path / "state"
        if accounts is None:
            accounts = [{"user": USER, "password_hash": PASSWORD_HASH}]
        inbox_config = InboxConfig.model_validate(
            {"host": "127.0.0.1", "port": 0, "accounts": accounts, **inbox}
        )
        gateway = GatewayConfig(state_dir=str(state), inbox=inbox_config, queue=queue)
        config = Config(gateway, tuple(files), tmp_path)
        tree = MappedTree(config.machines)
        service = JobService(config, tree, environ=environ or {})
        async with service:
            task = asyncio.create_task(service.run(), name="test:jobs")
            try:
                yield Harness(service, tree, state)
            finally:
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)

    yield build


class Renames(logging.Handler):
    """Counts completed uploads on the simulator's store (it logs every RNTO)."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.targets: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        if record.getMessage().startswith("renamed "):
            self.targets.append(record.getMessage().rsplit(" to ", 1)[-1])


@pytest.fixture
def renames() -> AsyncIterator[Renames]:
    handler = Renames()
    logger = logging.getLogger("simulator.ftp")
    old = logger.level
    logger.setLevel(logging.INFO)
    logger.addHandler(handler)
    yield handler
    logger.removeHandler(handler)
    logger.setLevel(old)

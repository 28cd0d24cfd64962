"""Starting, asking and stopping the benchmark's processes: agents, Mosquitto, the gateway CLI.

Each agent (bench/agents/) is a `python -m bench.agents.<name>` child that speaks
one JSON line per command (bench/agents/protocol.py). Its stderr goes to a log
file in the run's work directory, so a failing party can be diagnosed after the
fact; the error message of a failed start names that file.
"""

from __future__ import annotations

import asyncio
import contextlib
import getpass
import json
import os
import random
import shutil
import signal
import socket
import sys
import time
from pathlib import Path
from typing import Any, Self

import psutil

ROOT = Path(__file__).resolve().parent.parent
MOSQUITTO = shutil.which("mosquitto") or "/usr/sbin/mosquitto"


class BenchError(Exception):
    """A party of the benchmark did not start or answer; the message says which and where its log is."""


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def listener_ports(count: int) -> int:
    """The first of `count` consecutive free ports below the ephemeral range, for `cnc-gateway fleet`'s
    base ports (shard K listens on base + K - 1: a port handed out by `free_port()` says nothing of the
    next one, and an outgoing connection took it once: shard 2's console could not listen)."""
    rng = random.Random()
    for _ in range(200):
        base = rng.randrange(20000, 32000 - count)
        held: list[socket.socket] = []
        try:
            for port in range(base, base + count):
                s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
                held.append(s)
                s.bind(("127.0.0.1", port))
        except OSError:
            continue
        finally:
            for s in held:
                s.close()
        return base
    raise RuntimeError(f"no {count} consecutive free ports below 32000")


def listener_port() -> int:
    """A free port below Linux's ephemeral range (32768-60999), for a server that restarts on it.

    While a server is down, a client reconnecting to 127.0.0.1:P can be given P itself as its source
    port and connect to itself (TCP's simultaneous open), or another process's outgoing connection
    can take P: the server's next start then fails with "Address already in use" (seen at the 13th
    of 30 broker restarts on a port from `free_port()`)."""
    rng = random.Random()
    for _ in range(200):
        port = rng.randrange(20000, 32000)
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port
    return free_port()


def child_env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    for key in ("http_proxy", "https_proxy", "all_proxy", "HTTP_PROXY", "HTTPS_PROXY", "ALL_PROXY"):
        env.pop(key, None)
    return env


class Agent:
    """One helper process; `await agent.ask("snap")` returns its answer as a dict."""

    def __init__(self, name: str, proc: asyncio.subprocess.Process, log: Path) -> None:
        self.name = name
        self.proc = proc
        self.log = log
        self.ready: dict[str, Any] = {}
        self._lock = asyncio.Lock()

    @property
    def pid(self) -> int:
        return self.proc.pid

    @classmethod
    async def start(
        cls, name: str, module: str, args: list[str], workdir: Path, *, timeout: float = 90.0
    ) -> Agent:
        log = workdir / f"{name}.log"
        with log.open("ab") as err:
            proc = await asyncio.create_subprocess_exec(
                sys.executable, "-m", module, *args,
                stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE, stderr=err,
                env=child_env(), cwd=str(ROOT), limit=64 << 20,
            )  # fmt: skip
        agent = cls(name, proc, log)
        try:
            agent.ready = await agent._read(timeout)
        except BenchError:
            await agent.kill()
            raise
        return agent

    async def _read(self, timeout: float) -> dict[str, Any]:
        assert self.proc.stdout is not None
        try:
            async with asyncio.timeout(timeout):
                line = await self.proc.stdout.readline()
        except TimeoutError:
            raise BenchError(f"{self.name} did not answer within {timeout:g} s (see {self.log})") from None
        if not line:
            await self.proc.wait()
            raise BenchError(
                f"{self.name} exited with {self.proc.returncode} (see {self.log}):\n{_tail(self.log)}"
            )
        return json.loads(line)

    async def ask(self, cmd: str, *, timeout: float = 60.0, **params: Any) -> dict[str, Any]:
        async with self._lock:
            assert self.proc.stdin is not None
            try:
                self.proc.stdin.write(json.dumps({"cmd": cmd, **params}).encode() + b"\n")
                await self.proc.stdin.drain()
            except (BrokenPipeError, ConnectionResetError):
                raise BenchError(f"{self.name} is gone (see {self.log}):\n{_tail(self.log)}") from None
            answer = await self._read(timeout)
        if not answer.get("ok", False):
            raise BenchError(f"{self.name}: {cmd} failed: {answer.get('error')} (see {self.log})")
        return answer

    async def stop(self, timeout: float = 10.0) -> dict[str, Any] | None:
        """Ask it to stop; kill it if it does not. Returns its last words (CPU, memory) if it answered."""
        answer = None
        if self.proc.returncode is None:
            with contextlib.suppress(BenchError, OSError, ValueError):
                answer = await self.ask("stop", timeout=timeout)
            try:
                async with asyncio.timeout(timeout):
                    await self.proc.wait()
            except TimeoutError:
                await self.kill()
        return answer

    async def kill(self) -> None:
        if self.proc.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                self.proc.kill()
            await self.proc.wait()


def _tail(path: Path, lines: int = 15) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return ""


class Mosquitto:
    """A private Mosquitto on a free port; no persistence, deep queues, a wide QoS 1 window, and
    Nagle's algorithm off towards its clients, as a latency-minded installation sets it.

    `persistence=True`: sessions and queued messages saved to its folder (on SIGTERM, and every
    second), so that `stop()` and `start()` keep a persistent subscriber's session; its port is then
    below the ephemeral range (`listener_port`), where no client can take it while it is down."""

    def __init__(self, workdir: Path, *, persistence: bool = False, unbounded: bool = False) -> None:
        self.dir = workdir / f"mosquitto-{time.monotonic_ns()}"
        self.persistence = persistence
        # `unbounded`: no limit on a subscriber's queue (count or bytes), so that the broker never drops
        # what it acknowledged to a publisher (issue 28's QoS 1 row); its notices are logged, and
        # `drops()` counts the "being dropped" ones, which must stay 0.
        self.unbounded = unbounded
        self.port = listener_port() if persistence else free_port()
        self.proc: asyncio.subprocess.Process | None = None

    async def __aenter__(self) -> Self:
        self.dir.mkdir(parents=True)
        persistence = (
            f"persistence true\npersistence_location {self.dir}/\nautosave_interval 1\n"
            if self.persistence
            else "persistence false\n"
        )
        (self.dir / "mosquitto.conf").write_text(
            f"listener {self.port} 127.0.0.1\n"
            "allow_anonymous true\n"
            f"user {getpass.getuser()}\n"
            f"{persistence}"
            + (
                "max_queued_messages 0\nmax_queued_bytes 0\nlog_type notice\n"
                if self.unbounded
                else "max_queued_messages 1000000\n"
            )
            + "max_inflight_messages 1000\n"
            "set_tcp_nodelay true\n"  # QoS 0 latency: see README, MQTT, "Latency at QoS 0"
            "log_dest stderr\nlog_type error\nlog_type warning\n",
            encoding="utf-8",
        )
        if not Path(MOSQUITTO).exists():
            raise BenchError("mosquitto is not installed (make system-deps installs it)")
        await self.start()
        return self

    def drops(self) -> int:
        """Mosquitto's notices that it dropped outgoing messages for a client (from its log)."""
        log = self.dir / "mosquitto.log"
        text = log.read_text(encoding="utf-8", errors="replace") if log.exists() else ""
        return sum(1 for line in text.splitlines() if "dropped" in line.lower())

    @property
    def pid(self) -> int:
        return self.proc.pid if self.proc is not None else 0

    async def start(self) -> None:
        """Start the broker (again) on its port, with its configuration; return once it listens."""
        with (self.dir / "mosquitto.log").open("ab") as log:
            self.proc = await asyncio.create_subprocess_exec(
                MOSQUITTO, "-c", str(self.dir / "mosquitto.conf"), stdout=log, stderr=log
            )
        deadline = time.monotonic() + 10
        while not _listening(self.port):
            if self.proc.returncode is not None or time.monotonic() > deadline:
                raise BenchError(f"mosquitto did not start (see {self.dir / 'mosquitto.log'})")
            await asyncio.sleep(0.02)

    async def restart(self) -> None:
        """Stop the broker (SIGTERM) and start it again on the same port (without persistence, every
        client loses its session)."""
        await self.stop()
        await self.start()

    async def stop(self) -> None:
        """SIGTERM (with persistence, Mosquitto saves its sessions and queues then); kill after 5 s."""
        if self.proc is not None and self.proc.returncode is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                async with asyncio.timeout(5):
                    await self.proc.wait()
            except TimeoutError:
                self.proc.kill()
                await self.proc.wait()

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()


def _listening(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.2)
        return s.connect_ex(("127.0.0.1", port)) == 0


class Meter:
    """CPU and memory of a process measured from outside (psutil), for processes that are not agents."""

    def __init__(self, pid: int) -> None:
        self.proc = psutil.Process(pid)
        self.peak_rss = 0.0

    def cpu(self) -> float:
        t = self.proc.cpu_times()
        return float(t.user + t.system)

    def rss(self) -> float:
        rss = float(self.proc.memory_info().rss)
        self.peak_rss = max(self.peak_rss, rss)
        return rss


def load_average() -> list[float]:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return []

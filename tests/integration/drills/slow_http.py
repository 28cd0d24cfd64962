"""What the HTTP security drill throws at a gateway, and how it measures the doors that must keep answering.

- `Siege`: N slow connections to one HTTP face, from several loopback addresses (`SiegeProcess` runs them
  in a process of their own): some send nothing, some send a request line and then one header line every
  few seconds (slow-loris), some (with `upload`) send complete headers of a large multipart POST and then
  drip its body. A connection the server closes is
  opened again a second later, as a slow-loris tool does, so the pressure lasts as long as the siege.
- `Probe`: one door's request, made again and again while the siege lasts: its worst latency and its
  failures (an error, or no answer within `LIMIT` seconds).
- `held_upload`: a multipart upload whose body is held back: does the server answer before the body is
  in, and does anything land in the staging folder meanwhile?
- `lands_on`: where a browser goes with a `Location` header (the WHATWG URL parser's habits that matter for
  open redirects: tabs and newlines removed, backslashes read as slashes).
"""

from __future__ import annotations

import asyncio
import contextlib
import multiprocessing
import os
import time
from collections import Counter
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import urljoin, urlsplit

LIMIT = 10.0  # s: a probe that takes longer has failed (the target is 1 s; this only catches a hang)
DRIP = 3.0  # s between the bytes a slow connection sends
RECONNECT = 1.0  # s before a slow connection the server closed is opened again
BOUNDARY = "drill-boundary"


def sources(count: int, *, crowd: int = 20) -> list[str]:
    """Where `count` slow connections come from: half from one address (the per-address cap), the rest
    spread over `crowd` others (the global cap)."""
    out = []
    for index in range(count):
        out.append("127.0.0.2" if index % 2 == 0 else f"127.0.0.{3 + (index // 2) % crowd}")
    return out


@dataclass
class Siege:
    """`count` slow connections to 127.0.0.1:`port`; `upload` names a path that takes multipart uploads."""

    port: int
    count: int
    upload: str | None = None
    opened: int = 0
    connect_failures: int = 0
    closed_by_server: int = 0
    open_now: int = 0
    peak_open: int = 0
    answers: Counter[str] = field(default_factory=Counter)  # first status line the server sent, by status
    _stop: asyncio.Event = field(default_factory=asyncio.Event)
    _tasks: list[asyncio.Task[None]] = field(default_factory=list)

    def start(self) -> Siege:
        for index, source in enumerate(sources(self.count)):
            kind = ("silent", "headers", "headers", "body" if self.upload else "headers")[index % 4]
            self._tasks.append(asyncio.create_task(self._one(index, source, kind), name=f"siege:{index}"))
        return self

    def figures(self) -> dict[str, Any]:
        return {
            "opened": self.opened,
            "connect_failures": self.connect_failures,
            "closed_by_server": self.closed_by_server,
            "open": self.open_now,
            "peak_open": self.peak_open,
            "answers": dict(self.answers),
        }

    async def stop(self) -> None:
        self._stop.set()
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)

    async def _one(self, index: int, source: str, kind: str) -> None:
        await asyncio.sleep((index % 100) / 100)  # not all in the same instant
        while not self._stop.is_set():
            try:
                reader, writer = await asyncio.wait_for(
                    asyncio.open_connection("127.0.0.1", self.port, local_addr=(source, 0)), LIMIT
                )
            except (OSError, TimeoutError):
                self.connect_failures += 1
                await asyncio.sleep(RECONNECT)
                continue
            self.opened += 1
            self.open_now += 1
            self.peak_open = max(self.peak_open, self.open_now)
            try:
                await self._drip(index, kind, reader, writer)
            except (OSError, TimeoutError):
                pass
            finally:
                self.open_now -= 1
                writer.transport.abort()
            if not self._stop.is_set():
                self.closed_by_server += 1
                await asyncio.sleep(RECONNECT)

    async def _drip(
        self, index: int, kind: str, reader: asyncio.StreamReader, writer: asyncio.StreamWriter
    ) -> None:
        """Send slowly until the server closes the connection."""
        if kind == "headers":
            writer.write(f"GET /current?drill={index} HTTP/1.1\r\nHost: drill\r\n".encode())
        elif kind == "body":
            head = (
                f'--{BOUNDARY}\r\nContent-Disposition: form-data; name="file"; filename="s{index}.nc"\r\n\r\n'
            )
            writer.write(
                f"POST {self.upload} HTTP/1.1\r\nHost: drill\r\nContent-Length: {64 * 1024 * 1024}\r\n"
                f"Content-Type: multipart/form-data; boundary={BOUNDARY}\r\n\r\n{head}".encode()
            )
        sent = 0
        first = True
        while True:
            try:
                data = await asyncio.wait_for(reader.read(4096), DRIP)
            except TimeoutError:
                sent += 1
                if kind == "headers":
                    writer.write(f"X-Drip-{sent}: {sent}\r\n".encode())
                elif kind == "body":
                    writer.write(b"G1 X1 Y1\n" * 100)
                await writer.drain()
                continue
            if not data:
                return
            if first:
                first = False
                line = data.split(b"\r\n", 1)[0].decode("latin-1")
                self.answers[line.split(" ")[1] if line.startswith("HTTP/") and " " in line else "other"] += 1


@dataclass(frozen=True)
class Target:
    name: str
    port: int
    count: int
    upload: str | None = None


class SiegeProcess:
    """Sieges in a process of their own: the probes' figures are then the gateway's, not the figures of an
    event loop that also runs thousands of slow connections. `stats` is each siege's latest report."""

    def __init__(self, targets: list[Target]) -> None:
        self.targets = targets
        ctx = multiprocessing.get_context("spawn")  # not fork: the test process has threads and a loop
        self._stop = ctx.Event()
        self._conn, child = ctx.Pipe(duplex=False)
        self._proc = ctx.Process(target=_siege_main, args=(targets, child, self._stop), name="siege")
        self.stats: dict[str, dict[str, Any]] = {t.name: {"opened": 0} for t in targets}

    def start(self) -> SiegeProcess:
        self._proc.start()
        return self

    def poll(self) -> dict[str, dict[str, Any]]:
        with contextlib.suppress(EOFError, OSError):  # the process has ended: its last report is kept
            while self._conn.poll():
                self.stats = self._conn.recv()
        return self.stats

    def opened(self) -> list[int]:
        return [int(self.poll()[t.name]["opened"]) for t in self.targets]

    def stop(self) -> dict[str, dict[str, Any]]:
        if self._proc.is_alive():
            self._stop.set()
            self._proc.join(30)
        if self._proc.is_alive():  # pragma: no cover - a siege that does not stop
            self._proc.kill()
            self._proc.join(5)
        return self.poll()


def _siege_main(targets: list[Target], conn: Any, stop: Any) -> None:
    asyncio.run(_sieges(targets, conn, stop))


async def _sieges(targets: list[Target], conn: Any, stop: Any) -> None:
    sieges = {t.name: Siege(t.port, t.count, t.upload).start() for t in targets}

    def report() -> None:
        conn.send({name: s.figures() for name, s in sieges.items()})

    while not stop.is_set():
        report()
        await asyncio.sleep(0.5)
    report()  # as it stood under the siege (open connections included)
    for siege in sieges.values():
        await siege.stop()


@dataclass
class Probe:
    """One door's request, repeated every `every` seconds until stopped."""

    name: str
    request: Callable[[], Awaitable[object]]
    every: float = 0.5
    latencies: list[float] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)

    async def run(self, stop: asyncio.Event) -> None:
        while not stop.is_set():
            started = time.monotonic()
            try:
                await asyncio.wait_for(self.request(), LIMIT)
            except Exception as exc:  # noqa: BLE001 - every failure is a finding to report
                self.failures.append(f"{type(exc).__name__}: {exc}"[:200])
            else:
                self.latencies.append(time.monotonic() - started)
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), self.every)

    @property
    def worst(self) -> float | None:
        return max(self.latencies) if self.latencies else None

    def figure(self) -> str:
        """`0.412s worst, p95 0.210s, median 0.031s of 77` (and the failures)."""
        got = sorted(self.latencies)
        if not got:
            text = "no answer"
        else:
            p95 = got[min(len(got) - 1, int(len(got) * 0.95))]
            text = f"{got[-1]:.3f}s worst, p95 {p95:.3f}s, median {got[len(got) // 2]:.3f}s of {len(got)}"
        return text + (f", {len(self.failures)} failed" if self.failures else "")


async def run_probes(probes: list[Probe], seconds: float) -> None:
    stop = asyncio.Event()
    tasks = [asyncio.create_task(p.run(stop), name=f"probe:{p.name}") for p in probes]
    await asyncio.sleep(seconds)
    stop.set()
    await asyncio.gather(*tasks)


@dataclass
class Held:
    status: str  # the status the server answered with before the body was in, or "" (no answer)
    seconds: float  # how long the answer took (LIMIT when there was none)
    staged: int  # files in the staging folder while the body was held back


async def held_upload(
    port: int,
    path: str,
    staging: Path,
    *,
    headers: dict[str, str] | None = None,
    method: str = "POST",
    wait: float = 5.0,
) -> Held:
    """A multipart upload with a 16 MiB Content-Length of which only the headers and 256 KiB are sent."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    started = time.monotonic()
    try:
        head = (
            f'--{BOUNDARY}\r\nContent-Disposition: form-data; name="machine"\r\n\r\nlaser-sim\r\n'
            f'--{BOUNDARY}\r\nContent-Disposition: form-data; name="file"; filename="held.nc"\r\n'
            "Content-Type: application/octet-stream\r\n\r\n"
        ).encode() + b"G1 X1 Y1 F100\n" * (256 * 1024 // 14)
        lines = [
            f"{method} {path} HTTP/1.1",
            "Host: drill",
            f"Content-Type: multipart/form-data; boundary={BOUNDARY}",
            f"Content-Length: {16 * 1024 * 1024}",
            *(f"{k}: {v}" for k, v in (headers or {}).items()),
        ]
        writer.write(("\r\n".join(lines) + "\r\n\r\n").encode() + head)
        with contextlib.suppress(ConnectionError):
            await writer.drain()
        staged = 0
        status = ""
        deadline = started + wait
        while time.monotonic() < deadline:
            staged = max(staged, count_files(staging))
            try:
                line = await asyncio.wait_for(reader.readline(), 0.05)
            except TimeoutError:
                continue
            except ConnectionError:
                break
            if line.startswith(b"HTTP/"):
                status = line.split()[1].decode()
            break
        seconds = time.monotonic() - started if status else wait
        staged = max(staged, count_files(staging))
        return Held(status, seconds, staged)
    finally:
        writer.transport.abort()


def cpu_seconds(pid: int) -> float:
    """User and system CPU time of a process so far (/proc/<pid>/stat)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def count_files(folder: Path) -> int:
    try:
        return sum(1 for p in folder.iterdir() if p.is_file())
    except FileNotFoundError:
        return 0


def lands_on(base: str, location: str) -> str:
    """The host a browser goes to when `base` answers with `location` (WHATWG: tab, LF and CR are removed
    anywhere, leading and trailing C0 controls and spaces trimmed, `\\` read as `/` in http(s) URLs)."""
    cleaned = (
        location.strip("".join(map(chr, range(0x21)))).replace("\t", "").replace("\n", "").replace("\r", "")
    )
    cleaned = cleaned.replace("\\", "/")
    return urlsplit(urljoin(base, cleaned)).netloc

"""The gateway's side of the DNC benchmark: its job service (gateway/jobs/service.py, with the serial lines
and their drip scheduler built from mappings as a user writes them) sending to the simulated device
servers, and the raw pyserial write the load figure is compared with. This process's CPU is the
gateway's in the fleet figure.

Commands: `drip` (urls, baud, programs, kinds, buffer, link, record, deadline): one drip job per line at
once through one job service, each line's mapping as the README has a user write it for its device
server's kind (`7bit`: the defaults; `transparent`: `software_parity: true`), the controller's buffer
told truthfully (`buffer`), `link` ({name, capacity}: the lines share a device server of that
capacity); with `record` the time (CLOCK_MONOTONIC) and size of every write to a device server's
socket; jobs not ended by `deadline` seconds are stopped (the service closes its lines) and reported
unfinished. `load` (url, baud, program, kind): one load job, seconds. `raw` (url, baud, program): the
framed program written to the port in one pyserial call. `sent_after` (holds: [from, to or null],
CLOCK_MONOTONIC): the characters written within each hold, from the last recorded drip. `restart` (url,
baud, program, line, repeats): a drip restarted at a line, the command's time per repeat.

A/B: `--gateway-source PATH` (bench.run's `--dnc-gateway LABEL=PATH`) imports `gateway` from another
checkout (a worktree of an older commit) instead of this one; the benchmark's own code stays this
checkout's. What it uses of the gateway is the configuration (mapping files, `Config`), the job service
(`JobService(config, tree)`, `submit_bytes`, `queue.list`) and the DNC codec's `LineSettings` and
`frame_program`; the timed writes are taken at the socket (`socket.socket.send`/`sendall`, `os.write`),
so they do not depend on how the gateway's serial lines are built. `restart` alone uses the serial
transport's own API (`SerialTransport`, `request_restart`).
"""

from __future__ import annotations

import argparse
import asyncio
import bisect
import contextlib
import hashlib
import itertools
import math
import os
import re
import socket
import stat
import subprocess
import sys
import time
from array import array
from collections.abc import Callable
from pathlib import Path
from typing import Any

import serial
import yaml

from bench.agents.protocol import process_stats, serve, setup_logging

ENDED = {"DELIVERED", "FAILED", "REJECTED", "CANCELLED"}
POLL = 0.2  # s between looks at the job queue while jobs run


def use_gateway(source: str | None) -> dict[str, str]:
    """Import `gateway` from `source` (another checkout) when given; where it came from, and its commit."""
    if source:
        root = Path(source).resolve()
        if not (root / "gateway" / "__init__.py").is_file():
            raise SystemExit(f"--gateway-source {source}: no gateway package there")
        if "gateway" in sys.modules:
            raise SystemExit("gateway was imported before --gateway-source could take effect")
        sys.path.insert(0, str(root))
    import gateway

    root = Path(gateway.__file__).resolve().parent.parent
    return {"gateway": str(root), "commit": _commit(root)}


def _commit(root: Path) -> str:
    def git(*args: str) -> str:
        done = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True, check=False)
        return done.stdout.strip() if done.returncode == 0 else ""

    head = git("rev-parse", "--short=12", "HEAD")
    if head and git("status", "--porcelain", "--untracked-files=no", "--", "gateway"):
        head += "+changes"
    return head


class WriteLog:
    """Every write to a device server's socket while recording: when (just before the call, so that a
    write racing a DC3 counts as after it) and how many bytes went. Taken at the socket, whatever the
    gateway's serial lines are built of (pyserial's socket:// port writes with `send`; an event loop's
    transport too). One line's worth (the after-DC3 figure drips one program)."""

    def __init__(self) -> None:
        self.times = array("d")
        self.counts = array("q")
        self.on = False
        self.ports: set[int] = set()
        self._ours: dict[int, bool] = {}
        send, sendall, write = socket.socket.send, socket.socket.sendall, os.write
        log = self

        def send_(sock: socket.socket, data: Any, *args: Any) -> int:
            if not log.on or not log._is_ours(sock.fileno()):
                return send(sock, data, *args)
            now = time.monotonic()
            n = send(sock, data, *args)
            log.add(now, n)
            return n

        def sendall_(sock: socket.socket, data: Any, *args: Any) -> None:
            if not log.on or not log._is_ours(sock.fileno()):
                return sendall(sock, data, *args)
            now = time.monotonic()
            sendall(sock, data, *args)
            log.add(now, len(memoryview(data)))
            return None

        def write_(fd: int, data: Any) -> int:
            if not log.on or not log._is_ours(fd):
                return write(fd, data)
            now = time.monotonic()
            n = write(fd, data)
            log.add(now, n)
            return n

        self._patched = (send_, sendall_, write_)
        self._originals = (send, sendall, write)

    def _install(self, on: bool) -> None:
        """The timing wrappers only while recording: at other times the gateway's process pays nothing for
        them (the fleet's CPU figure is the gateway's own)."""
        send, sendall, write = self._patched if on else self._originals
        socket.socket.send = send  # type: ignore[method-assign]
        socket.socket.sendall = sendall  # type: ignore[method-assign]
        os.write = write

    def stop(self) -> None:
        self.on = False
        self._install(False)

    def _is_ours(self, fd: int) -> bool:
        """A TCP socket to one of the device servers (not the event loop's self-pipe, not stdout)."""
        known = self._ours.get(fd)
        if known is None:
            known = False
            with contextlib.suppress(OSError, ValueError):
                if stat.S_ISSOCK(os.fstat(fd).st_mode):
                    with socket.socket(fileno=os.dup(fd)) as probe:
                        peer = probe.getpeername()
                        known = isinstance(peer, tuple) and peer[1] in self.ports
            self._ours[fd] = known
        return known

    def add(self, when: float, count: int) -> None:
        self.times.append(when)
        self.counts.append(count)

    def start(self, ports: set[int]) -> None:
        self.times, self.counts, self.ports, self._ours, self.on = array("d"), array("q"), ports, {}, True
        self._install(True)

    def within(self, holds: list[list[float | None]]) -> list[int]:
        """Characters written after each hold's DC3 and before its DC1."""
        totals = [0, *itertools.accumulate(self.counts)]
        out = []
        for start, end in holds:
            assert start is not None
            a = bisect.bisect_right(self.times, start)
            b = bisect.bisect_left(self.times, math.inf if end is None else end)
            out.append(totals[b] - totals[a])
        return out


def mapping(machine: str, url: str, baud: int, kind: str, *, mode: str, buffer: int, **more: Any) -> str:
    """A serial machine's mapping as the README has a user write it for a device server of `kind`."""
    controller = {
        "type": "serial",
        "where": url,
        "baud": baud,
        "mode": mode,
        "buffer": buffer,
        "dc1_timeout": 30,
        **more,
    }
    if kind == "transparent":
        controller["software_parity"] = True  # an 8-bit port: the parity bit travels as bit 7
    elif kind != "7bit":
        raise ValueError(f"device server kind {kind!r}: 7bit or transparent")
    return yaml.safe_dump(
        {
            "machine": machine,
            "driver": {"endpoint": "opc.tcp://127.0.0.1:1"},  # never connected: the job service alone runs
            "variables": [
                {"path": "Machine/State", "source": "ns=2;s=::AsGlobalPV:gMachine.State", "type": "Int16"}
            ],
            "jobs": {"controller": controller, "max_attempts": 1},
        },
        sort_keys=False,
    )


def _port_of(url: str) -> int:
    return int(url.rsplit(":", 1)[1].rstrip("/"))


async def main(workdir: Path) -> None:
    from gateway.codecs.dnc import LineSettings, frame_program
    from gateway.config.gateway import GatewayConfig
    from gateway.config.loader import Config, load_mapping
    from gateway.jobs.service import JobService
    from gateway.model.tree import VariableTree

    log = WriteLog()
    runs = itertools.count()

    async def jobs(
        lines: list[tuple[str, str]], programs: list[Path], deadline: float, started_cb: Callable[[], None]
    ) -> dict[str, Any]:
        """One job per (machine, mapping) through one job service, until every one ended or `deadline`."""
        folder = workdir / f"run-{next(runs):03d}"
        folder.mkdir(parents=True)
        mappings = []
        for machine, text in lines:
            path = folder / f"{machine}.yaml"
            path.write_text(text, encoding="utf-8")
            mappings.append(load_mapping(path, environ={}))
        state = str(folder / "state")
        gateway = GatewayConfig.model_validate({"state_dir": state, "inbox": {"enabled": False}})
        config = Config(gateway, tuple(mappings), folder)
        tree = VariableTree(m.definition() for m in mappings)
        unfinished: list[str] = []
        async with JobService(config, tree, environ={}) as service:
            task = asyncio.create_task(service.run(), name="bench:jobs")
            try:
                datas = [p.read_bytes() for p in programs]
                before = process_stats()
                started = time.monotonic()
                started_cb()
                for (machine, _text), path, data in zip(lines, programs, datas, strict=True):
                    reply = await service.submit_bytes(machine, path.name, data, user="bench", origin="bench")
                    if not reply.ok:
                        raise RuntimeError(f"{machine}: {path.name} refused: {reply.message}")
                ended_at: dict[str, float] = {}
                while True:
                    listed = service.queue.list(limit=1000, newest_first=False)
                    now = time.monotonic()
                    for job in listed:
                        if str(job.state) in ENDED:
                            ended_at.setdefault(job.machine, now - started)
                    if len(ended_at) == len(lines):
                        break
                    if now - started > deadline:
                        unfinished = sorted({m for m, _ in lines} - set(ended_at))
                        break
                    await asyncio.sleep(POLL)
                wall = time.monotonic() - started
                after = process_stats()
            finally:
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)
            # Leaving the service closes its lines: a transfer past its deadline stops there.
        by_machine = {j.machine: j for j in listed}
        return {
            "seconds": wall,
            "cpu_share": (after["cpu"] - before["cpu"]) / wall if wall > 0 else None,
            "unfinished": unfinished,
            "jobs": {
                m: {
                    "state": str(j.state),
                    "reason": j.reason,
                    "seconds": ended_at.get(m),
                    "dc3": _dc3(j.reason),
                }
                for m, j in by_machine.items()
            },
            "failures": [
                f"{m}: {j.reason}"
                for m, j in by_machine.items()
                if str(j.state) in ENDED and str(j.state) != "DELIVERED"
            ],
        }

    async def drip(request: dict[str, Any]) -> dict[str, Any]:
        urls: list[str] = request["urls"]
        kinds = request.get("kinds") or ["7bit"] * len(urls)
        link = request.get("link")  # {"name": …, "capacity": chars/s}: the lines share one device server
        shared = {"link": link["name"], "link_capacity": float(link["capacity"])} if link else {}
        baud, buffer = int(request["baud"]), int(request.get("buffer", 256))
        lines = [
            (f"m{i:02d}", mapping(f"m{i:02d}", url, baud, kind, mode="drip", buffer=buffer, **shared))
            for i, (url, kind) in enumerate(zip(urls, kinds, strict=True))
        ]
        log.stop()
        record = bool(request.get("record"))
        answer = await jobs(
            lines,
            [Path(p) for p in request["programs"]],
            float(request.get("deadline", math.inf)),
            lambda: log.start({_port_of(u) for u in urls}) if record else None,
        )
        log.stop()
        return answer

    async def load(request: dict[str, Any]) -> dict[str, Any]:
        url, baud = request["url"], int(request["baud"])
        text = mapping("m00", url, baud, request.get("kind", "7bit"), mode="load", buffer=256)
        answer = await jobs([("m00", text)], [Path(request["program"])], math.inf, lambda: None)
        if answer["failures"]:
            raise RuntimeError("; ".join(answer["failures"]))
        return {"seconds": answer["jobs"]["m00"]["seconds"], "reason": answer["jobs"]["m00"]["reason"]}

    def raw_write(url: str, baud: int, path: Path) -> float:
        line = LineSettings(baud=baud)  # a 7-bit device server: its UART does the parity
        wire = frame_program(path.read_bytes(), line).data
        port = serial.serial_for_url(url, baudrate=baud, timeout=0, write_timeout=None)
        started = time.monotonic()
        try:
            port.write(wire)
            port.flush()
            written = time.monotonic() - started
            # Closing a socket:// port drops what the device server has not read yet: keep it open
            # until the line has carried it all (and a little longer).
            time.sleep(max(0.0, len(wire) / line.bytes_per_second - written) + 2.0)
        finally:
            port.close()
        return written

    async def raw(request: dict[str, Any]) -> dict[str, Any]:
        seconds = await asyncio.to_thread(
            raw_write, request["url"], int(request["baud"]), Path(request["program"])
        )
        return {"seconds": seconds}

    async def restart(request: dict[str, Any]) -> dict[str, Any]:
        from gateway.transports.base import Program, Progress
        from gateway.transports.dnc.config import ControllerSerial
        from gateway.transports.dnc.transport import SerialTransport, request_restart

        def ignore(_progress: Progress) -> None:
            pass

        path = Path(request["program"])
        data = path.read_bytes()
        prog = Program(path.name, path, len(data), hashlib.sha256(data).hexdigest(), None, "bench")
        settings = ControllerSerial.model_validate(
            {
                "type": "serial",
                "where": request["url"],
                "baud": int(request["baud"]),
                "mode": "drip",
                "dc1_timeout": 30,
            }
        )
        commands: list[float] = []
        for _ in range(int(request.get("repeats", 3))):
            line = SerialTransport(settings, machine="bench", state_dir=workdir)
            try:
                commands.append(time.monotonic())
                request_restart(path, int(request["line"]))  # the operator's command
                await line.deliver(prog, ignore)
            finally:
                line.close()
            await asyncio.sleep(float(request.get("pause", 0.5)))  # the controller back to reading
        return {"commands": commands}

    def sent_after(request: dict[str, Any]) -> dict[str, Any]:
        return {"counts": log.within(request["holds"]), "writes": len(log.times)}

    await serve(
        {"load": load, "raw": raw, "drip": drip, "sent_after": sent_after, "restart": restart},
        ready=READY,
    )


def _dc3(reason: str) -> int | None:
    """The DC3s a job's record says the gateway saw ("…; 12 DC3, at most 3 characters after one)")."""
    match = re.search(r"(\d[\d,]*) DC3", reason or "")
    return int(match.group(1).replace(",", "")) if match else None


READY: dict[str, str] = {}

if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("--workdir", type=Path, required=True)
    parser.add_argument(
        "--gateway-source",
        default=os.environ.get("BENCH_DNC_GATEWAY_SOURCE") or None,
        metavar="PATH",
        help="a checkout whose gateway/ to run (A/B against an older commit); default: this one",
    )
    setup_logging()
    args = parser.parse_args()
    READY.update(use_gateway(args.gateway_source))
    asyncio.run(main(args.workdir))

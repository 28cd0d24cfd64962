"""How the orchestrator talks to its helper processes: one JSON object per line, both ways.

An agent prints `{"event": "ready", ...}` once it is set up, then answers every
command line (`{"cmd": "snap"}`, `{"cmd": "rate", "rate": 5000}`) with exactly
one JSON line. `stop` (or the end of stdin) ends it. Logs go to stderr, which
the orchestrator sends to a file. Every answer carries the process's own CPU
time and memory, so no figure depends on sampling from outside.
"""

from __future__ import annotations

import asyncio
import inspect
import json
import logging
import os
import resource
import sys
import threading
import time
from collections.abc import Awaitable, Callable
from typing import Any

import psutil

Handler = Callable[[dict[str, Any]], "dict[str, Any] | Awaitable[dict[str, Any]]"]

_PROCESS = psutil.Process()


def process_stats() -> dict[str, float]:
    """CPU seconds used so far, current and peak resident memory (bytes), and the wall clock."""
    cpu = _PROCESS.cpu_times()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return {
        "cpu": cpu.user + cpu.system,
        "rss": float(_PROCESS.memory_info().rss),
        "maxrss": float(peak * 1024 if sys.platform != "darwin" else peak),
        "wall": time.time(),
        "mono": time.monotonic(),
    }


def emit(message: dict[str, Any]) -> None:
    sys.stdout.write(json.dumps(message, default=str) + "\n")
    sys.stdout.flush()


def setup_logging(level: int = logging.WARNING) -> None:
    logging.basicConfig(
        level=level, stream=sys.stderr, format="%(asctime)s %(levelname)s %(name)s: %(message)s", force=True
    )


async def serve(handlers: dict[str, Handler], ready: dict[str, Any] | None = None) -> None:
    """Announce readiness, then answer commands from stdin until `stop` or EOF."""
    loop = asyncio.get_running_loop()
    reader = asyncio.StreamReader(limit=1 << 20)
    await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), sys.stdin)
    emit({"event": "ready", "pid": os.getpid(), **(ready or {}), **process_stats()})
    while True:
        line = await reader.readline()
        if not line:
            return
        request = json.loads(line)
        cmd = request.get("cmd")
        if cmd == "stop":
            emit({"ok": True, **process_stats()})
            return
        handler = handlers.get(cmd)
        if handler is None:
            emit({"ok": False, "error": f"unknown command {cmd!r}"})
            continue
        try:
            answer = handler(request)
            if inspect.isawaitable(answer):
                answer = await answer
        except Exception as exc:  # the orchestrator reports it; the agent keeps serving
            logging.getLogger("agent").exception("command %s failed", cmd)
            emit({"ok": False, "error": f"{type(exc).__name__}: {exc}"})
            continue
        emit({"ok": True, **answer, **process_stats()})


def serve_in_thread(
    handlers: dict[str, Callable[[dict[str, Any]], dict[str, Any]]],
    on_stop: Callable[[], None],
    ready: dict[str, Any] | None = None,
) -> threading.Thread:
    """The same protocol for agents whose main thread belongs to a library's network loop (paho)."""

    def run() -> None:
        emit({"event": "ready", "pid": os.getpid(), **(ready or {}), **process_stats()})
        for line in sys.stdin:
            request = json.loads(line)
            cmd = request.get("cmd")
            if cmd == "stop":
                break
            handler = handlers.get(cmd)
            if handler is None:
                emit({"ok": False, "error": f"unknown command {cmd!r}"})
                continue
            try:
                emit({"ok": True, **handler(request), **process_stats()})
            except Exception as exc:
                logging.getLogger("agent").exception("command %s failed", cmd)
                emit({"ok": False, "error": f"{type(exc).__name__}: {exc}"})
        on_stop()
        emit({"ok": True, **process_stats()})

    thread = threading.Thread(target=run, name="agent-commands", daemon=True)
    thread.start()
    return thread


def percentiles(values: list[float]) -> dict[str, float | None]:
    """p50, p99 and max of a list (None when empty)."""
    if not values:
        return {"p50": None, "p99": None, "max": None, "n": 0}
    ordered = sorted(values)
    n = len(ordered)

    def at(q: float) -> float:
        return ordered[min(n - 1, max(0, round(q * (n - 1))))]

    return {"p50": at(0.50), "p99": at(0.99), "max": ordered[-1], "n": n}

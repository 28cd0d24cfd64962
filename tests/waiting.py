"""Deadline-based waiting for tests: poll a condition instead of sleeping a fixed time."""

from __future__ import annotations

import asyncio
import inspect
import random
import socket
import time
from collections.abc import Awaitable, Callable
from typing import Any, TypeVar

T = TypeVar("T")


async def wait_until(
    condition: Callable[[], Any | Awaitable[Any]],
    *,
    timeout: float = 10.0,
    interval: float = 0.02,
    message: str = "condition",
) -> Any:
    """Poll `condition` (sync or async) until it returns something truthy; return that.

    Raises AssertionError naming `message` and the last value seen if the deadline passes.
    """
    deadline = time.monotonic() + timeout
    last: Any = None
    while True:
        result = condition()
        if inspect.isawaitable(result):
            result = await result
        if result:
            return result
        last = result
        if time.monotonic() >= deadline:
            raise AssertionError(f"timed out after {timeout}s waiting for {message} (last value: {last!r})")
        await asyncio.sleep(interval)


def wait_until_sync(
    condition: Callable[[], T], *, timeout: float = 10.0, interval: float = 0.02, message: str = "condition"
) -> T:
    deadline = time.monotonic() + timeout
    while True:
        result = condition()
        if result:
            return result
        if time.monotonic() >= deadline:
            raise AssertionError(f"timed out after {timeout}s waiting for {message} (last value: {result!r})")
        time.sleep(interval)


# Below Linux's ephemeral range (32768-60999): a port the kernel picks for bind(0) is one it may also give
# any outgoing connection as its local port before the test's server binds it (seen in CI: an OPC UA sink's
# port "already in use" between free_port() and the bind). Ports from here are never handed out that way.
_PORTS = range(20000, 32768)
# Ports are handed out in turn, this far apart: a test may use the few ports after one it was given (the
# fleet's shards take base + K - 1), and the next port handed out is not among them.
STRIDE = 8
_next = [random.randrange(len(_PORTS))]  # a random start, so two runs side by side rarely meet


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now; this run hands the same one out again
    only after some 1,600 others (two servers of one test never share one)."""
    for _ in range(len(_PORTS) // STRIDE):
        port = _PORTS[_next[0] % len(_PORTS)]
        _next[0] += STRIDE
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
        return port
    raise RuntimeError(f"no free TCP port in {_PORTS.start}-{_PORTS.stop - 1}")

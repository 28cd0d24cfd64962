"""The serial lines' one I/O thread (gateway/transports/dnc/lineio.py), on real descriptors: socketpairs."""

from __future__ import annotations

import contextlib
import math
import socket
import threading
import time
from collections.abc import Iterator

import pytest

from gateway.transports.dnc import lineio
from gateway.transports.dnc.lineio import LineLoop
from tests.waiting import wait_until_sync

DEADLINE = 10.0


class Reader:
    """A task that reads its socket until it sees `!`; it wants no step on the clock (due = inf)."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self.sock.setblocking(False)
        self.due = math.inf
        self.got = bytearray()
        self.threads: set[str] = set()

    def fileno(self) -> int | None:
        return self.sock.fileno()

    def step(self, now: float, readable: bool) -> bool:
        self.threads.add(threading.current_thread().name)
        if readable:
            with contextlib.suppress(BlockingIOError):
                self.got += self.sock.recv(4096)
        return b"!" in self.got


class Ticker:
    """A task without a descriptor (as an rfc2217:// port): looked at every lineio.POLL (readable, since
    only reading tells), and acting when its clock says, `count` times."""

    def __init__(self, every: float, count: int, *, fail_at: int | None = None) -> None:
        self.every = every
        self.count = count
        self.fail_at = fail_at
        self.due = 0.0
        self.steps: list[float] = []

    def fileno(self) -> int | None:
        return None

    def step(self, now: float, readable: bool) -> bool:
        assert readable  # a port without a descriptor is always worth a look
        if now < self.due:
            return False
        self.steps.append(now)
        if self.fail_at is not None and len(self.steps) == self.fail_at:
            raise RuntimeError("the port failed")
        self.due = now + self.every
        return len(self.steps) >= self.count


@pytest.fixture
def loop() -> Iterator[LineLoop]:
    yield LineLoop("dnc-io-test")


def test_calls_run_on_the_io_thread_and_hand_back_results_and_errors(loop: LineLoop) -> None:
    assert loop.call(lambda: threading.current_thread().name).result(DEADLINE) == "dnc-io-test"

    def broken() -> None:
        raise OSError("no such port")

    with pytest.raises(OSError, match="no such port"):
        loop.call(broken).result(DEADLINE)


def test_a_task_is_stepped_when_its_port_has_something_and_ends_when_it_says(loop: LineLoop) -> None:
    mine, theirs = socket.socketpair()
    with mine, theirs:
        task = Reader(mine)
        done = loop.attach(task)
        theirs.sendall(b"DC1")
        wait_until_sync(lambda: bytes(task.got) == b"DC1", timeout=DEADLINE, message="the bytes read")
        assert not done.done()
        theirs.sendall(b"!")
        done.result(DEADLINE)
        assert task.threads == {"dnc-io-test"}


def test_many_tasks_share_the_thread_and_one_failing_stops_only_itself(loop: LineLoop) -> None:
    pairs = [socket.socketpair() for _ in range(5)]
    try:
        readers = [Reader(mine) for mine, _ in pairs]
        futures = [loop.attach(task) for task in readers]
        ticker = Ticker(0.005, 20)
        broken = Ticker(0.005, 20, fail_at=3)
        ticking, failing = loop.attach(ticker), loop.attach(broken)
        with pytest.raises(RuntimeError, match="the port failed"):
            failing.result(DEADLINE)
        for _, theirs in pairs:
            theirs.sendall(b"x!")
        for future in futures:
            future.result(DEADLINE)
        ticking.result(DEADLINE)
        assert len(ticker.steps) == 20 and len(broken.steps) == 3
        # Stepped on its clock, never before it was due (the grace aside).
        gaps = [b - a for a, b in zip(ticker.steps, ticker.steps[1:], strict=False)]
        assert min(gaps) >= 0.005 - lineio.GRACE - 1e-6
        assert {name for task in readers for name in task.threads} == {"dnc-io-test"}
    finally:
        for mine, theirs in pairs:
            mine.close()
            theirs.close()


def test_a_task_cancelled_before_the_thread_took_it_is_never_stepped(loop: LineLoop) -> None:
    busy = threading.Event()
    release = threading.Event()

    def hold() -> None:
        busy.set()
        release.wait(DEADLINE)

    held = loop.call(hold)
    assert busy.wait(DEADLINE)
    ticker = Ticker(0.001, 5)
    future = loop.attach(ticker)
    assert future.cancel()
    release.set()
    held.result(DEADLINE)
    loop.call(lambda: None).result(DEADLINE)  # the thread has looked at its new tasks since
    assert ticker.steps == []


def test_the_thread_ends_when_idle_and_comes_back_for_the_next_call(
    loop: LineLoop, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(lineio, "IDLE_EXIT", 0.05)
    loop.call(lambda: None).result(DEADLINE)
    wait_until_sync(lambda: not loop.running, timeout=DEADLINE, message="the idle thread ended")
    started = time.monotonic()
    assert loop.call(lambda: 42).result(DEADLINE) == 42
    assert time.monotonic() - started < DEADLINE
    loop.wake()  # after the thread ended and again: never a write to a closed or reused descriptor

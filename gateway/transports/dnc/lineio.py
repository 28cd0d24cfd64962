"""One thread for every serial line of a gateway: the ports' reads, the paced writes, the timers.

A drip-feed writes a slice of a few characters every few milliseconds and must
see the controller's DC3 before its next slice. With a thread per line, twenty
lines woke twenty threads hundreds of times a second each (37 % of a core in the
bench). Here one thread serves them all: it waits in one selector on every open
port's descriptor (device paths, socket://) and on a wake pipe, steps each task
(a transfer, transfer.py) whose port has something to read or whose next slice is
due, and goes back to waiting. Tasks due within `GRACE` of each other are stepped
together, so that lines paced alike share a wake-up.

An rfc2217:// port has no descriptor (pyserial's RFC 2217 client reads in a thread
of its own): its task is stepped at least every `POLL` seconds instead.

Nothing that may wait runs here: opening a port (a TCP connect, the RFC 2217
negotiation) and closing one stay on the caller's side (`asyncio.to_thread`).
The thread starts with its first task or call and ends when it has had nothing
to do for `IDLE_EXIT` seconds.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import selectors
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any, Protocol, TypeVar

log = logging.getLogger("gateway.jobs.dnc")

T = TypeVar("T")


GRACE = 0.0005  # s: tasks due this close to now are stepped now, with the one that woke the thread
POLL = 0.002  # s between looks at a port without a descriptor
IDLE_EXIT = 2.0  # s the thread waits with nothing to do before it ends


class LineTask(Protocol):
    """What the thread steps (a transfer). `due`: when it wants its next step (math.inf: only when its port
    has something to read); `step` returns True when the task is finished (its result is its own)."""

    due: float

    def fileno(self) -> int | None: ...

    def step(self, now: float, readable: bool) -> bool: ...


class LineLoop:
    """The I/O thread of a gateway's serial lines. Thread-safe: `attach` and `call` from any thread."""

    def __init__(self, name: str = "dnc-io") -> None:
        self.name = name
        self._lock = threading.Lock()
        self._calls: deque[tuple[Callable[[], Any], Future[Any]]] = deque()
        self._new: deque[tuple[LineTask, Future[None]]] = deque()
        self._tasks: dict[LineTask, Future[None]] = {}
        self._thread: threading.Thread | None = None
        self._selector: selectors.BaseSelector | None = None
        self._wake_r = self._wake_w = -1
        self.wakeups = 0  # times the thread woke (the bench's figure of its cost)

    # --- any thread --------------------------------------------------------------------------------

    def call(self, fn: Callable[[], T]) -> Future[T]:
        """Run `fn` on the I/O thread (a read between transfers, a port's last look); its result or error
        in the future."""
        future: Future[T] = Future()
        with self._lock:
            self._calls.append((fn, future))
            self._ensure_running()
        self.wake()
        return future

    def attach(self, task: LineTask) -> Future[None]:
        """Step `task` until it says it is finished; the future is done then (with the error a step raised,
        if one did: the task is dropped)."""
        future: Future[None] = Future()
        with self._lock:
            self._new.append((task, future))
            self._ensure_running()
        self.wake()
        return future

    def wake(self) -> None:
        """Make the thread look at its tasks now (a task's `due` changed from another thread)."""
        with self._lock:  # the pipe closes with the thread: never write to a descriptor number reused since
            if self._wake_w >= 0:
                with contextlib.suppress(BlockingIOError, OSError):  # a full pipe is awake already
                    os.write(self._wake_w, b".")

    @property
    def running(self) -> bool:
        return self._thread is not None

    # --- the thread --------------------------------------------------------------------------------

    def _ensure_running(self) -> None:
        """Start the thread (the lock held)."""
        if self._thread is not None:
            return
        self._selector = selectors.DefaultSelector()
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._selector.register(self._wake_r, selectors.EVENT_READ, None)
        # A daemon: a gateway stopping aborts its transfers first (SerialTransport.close); the thread then
        # has nothing left and ends, and never holds the interpreter's exit meanwhile.
        self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        selector = self._selector
        assert selector is not None
        idle_since = time.monotonic()
        try:
            while True:
                self._take_new(selector)
                if not self._run_calls() and not self._tasks:
                    now = time.monotonic()
                    if now - idle_since >= IDLE_EXIT and self._stop_if_idle():
                        return
                else:
                    idle_since = time.monotonic()
                timeout = self._timeout()
                events = selector.select(timeout)
                self.wakeups += 1
                readable: set[LineTask] = set()
                for key, _mask in events:
                    if key.data is None:
                        with contextlib.suppress(BlockingIOError, OSError):
                            while os.read(self._wake_r, 256):
                                pass
                    else:
                        readable.add(key.data)
                self._step_tasks(selector, readable)
        except BaseException:  # a bug here must not leave every line hanging in silence
            log.exception("the serial lines' I/O thread failed")
            self._fail_all(selector)
            raise

    def _timeout(self) -> float:
        with self._lock:
            if self._calls or self._new:
                return 0.0
        due = math.inf
        for task in self._tasks:
            due = min(due, task.due if task.fileno() is not None else min(task.due, time.monotonic() + POLL))
        if not self._tasks:
            return IDLE_EXIT
        return min(IDLE_EXIT, max(0.0, due - time.monotonic()))

    def _take_new(self, selector: selectors.BaseSelector) -> None:
        with self._lock:
            new, self._new = self._new, deque()
        for task, future in new:
            if not future.set_running_or_notify_cancel():
                continue  # cancelled before it was ever stepped
            fd = task.fileno()
            try:
                if fd is not None:
                    selector.register(fd, selectors.EVENT_READ, task)
            except (OSError, ValueError, KeyError) as exc:
                future.set_exception(exc)
                continue
            self._tasks[task] = future

    def _run_calls(self) -> bool:
        with self._lock:
            calls, self._calls = self._calls, deque()
        for fn, future in calls:
            if not future.set_running_or_notify_cancel():
                continue
            try:
                future.set_result(fn())
            except BaseException as exc:  # handed to the caller, who awaits it  # noqa: BLE001
                future.set_exception(exc)
        return bool(calls)

    def _step_tasks(self, selector: selectors.BaseSelector, readable: set[LineTask]) -> None:
        now = time.monotonic()
        for task in list(self._tasks):
            polled = task.fileno() is None
            is_readable = task in readable or polled
            if not is_readable and task.due > now + GRACE:
                continue
            try:
                finished = task.step(now, is_readable)
            except BaseException as exc:  # the task's failure is its caller's to handle  # noqa: BLE001
                self._drop(selector, task).set_exception(exc)
                continue
            if finished:
                self._drop(selector, task).set_result(None)

    def _drop(self, selector: selectors.BaseSelector, task: LineTask) -> Future[None]:
        future = self._tasks.pop(task)
        fd = task.fileno()
        if fd is not None:
            with contextlib.suppress(KeyError, ValueError, OSError):
                selector.unregister(fd)
        return future

    def _stop_if_idle(self) -> bool:
        """End the thread if nothing came meanwhile (the lock makes the check and the end one step)."""
        with self._lock:
            if self._calls or self._new or self._tasks:
                return False
            self._close_locked()
            return True

    def _close_locked(self) -> None:
        selector, self._selector = self._selector, None
        if selector is not None:
            selector.close()
        for fd in (self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)
        self._wake_r = self._wake_w = -1
        self._thread = None

    def _fail_all(self, selector: selectors.BaseSelector) -> None:
        error = RuntimeError("the serial lines' I/O thread failed (see the log)")
        for task in list(self._tasks):
            self._drop(selector, task).set_exception(error)
        with self._lock:
            for _fn, future in self._calls:
                future.set_exception(error)
            for _task, future in self._new:
                future.set_exception(error)
            self._calls.clear()
            self._new.clear()
            self._close_locked()

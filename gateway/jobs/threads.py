"""The job queue's own workers: a thread for the queue file, two for checks and file copies, one that
checks uploads as they stream in, and one process for validating large programs otherwise, started
when a client first logs in to the inbox.

Blocking work (SQLite, reading and validating programs) runs off the event loop,
but not in asyncio's shared default executor: that pool is small (cores + 4)
and anything else in the process that blocks in it (a crowd of slow clients,
another component) would stall the queue. One thread for the queue file also
serialises its use without a lock held across awaits.

Validating a large program is seconds of pure-Python CPU, and a thread holds the
GIL meanwhile: the event loop (OPC UA, MQTT) would stall. That work goes to a
separate process, started with "spawn" (forking a threaded process can copy a
held lock into the child).

That process ignores SIGINT. Ctrl-C at a terminal reaches the whole process
group, the worker too, which would die with a KeyboardInterrupt traceback while
the gateway shuts down cleanly; the gateway stops it itself (`shutdown`). SIGINT
is blocked while the process is spawned, so that it starts with it blocked and
ignores it before unblocking it: a Ctrl-C during its start-up is lost, not a
traceback (the stdlib's resource tracker starts the same way).
"""

from __future__ import annotations

import asyncio
import functools
import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ProcessPoolExecutor, ThreadPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from typing import Any, TypeVar

T = TypeVar("T")


class JobThreads:
    def __init__(self, workers: int = 2) -> None:
        self._queue = ThreadPoolExecutor(1, thread_name_prefix="jobs-queue")
        self._work = ThreadPoolExecutor(workers, thread_name_prefix="jobs-work")
        self._check = ThreadPoolExecutor(1, thread_name_prefix="jobs-check")
        self._processes: ProcessPoolExecutor | None = None
        self._lock = threading.Lock()
        self._closed = False

    async def queue(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        """Run a JobQueue call."""
        return await asyncio.get_running_loop().run_in_executor(
            self._queue, functools.partial(fn, *args, **kwargs)
        )

    async def work(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        """Run file I/O or a validation."""
        return await asyncio.get_running_loop().run_in_executor(
            self._work, functools.partial(fn, *args, **kwargs)
        )

    def checking(self, fn: Callable[..., T], *args: Any) -> Future[T]:
        """Run `fn(*args)` in the check thread, after every call submitted before it (uploads checked as
        they stream in; see upload_check.py)."""
        return self._check.submit(fn, *args)

    async def process(self, fn: Callable[..., T], *args: Any) -> T:
        """Run `fn(*args)` in the validation process (fn, args and result must pickle).

        If the process dies (killed, out of memory), this call raises BrokenProcessPool
        and the next call starts a new process.
        """
        pool = self._pool()
        try:
            with interrupts_held():  # the call may spawn the process
                future = pool.submit(fn, *args)
            return await asyncio.wrap_future(future)
        except BrokenProcessPool:
            with self._lock:
                if self._processes is pool:
                    self._processes = None
            pool.shutdown(wait=False, cancel_futures=True)
            raise

    def warm(self, ready: Callable[[], Any] = os.getpid) -> None:
        """Start the validation process now, if it is not running: uploads are on their way.

        Starting a Python process takes a few tenths of a second, as long as a large
        upload takes on a LAN; started at the login, it is ready when the upload is
        committed. The process then stays for the gateway's lifetime. `ready` is run
        in it, so that what the first real call needs is imported by then.
        """
        try:
            pool = self._pool()
        except RuntimeError:
            return  # shut down
        if not getattr(pool, "_processes", None):
            with interrupts_held():
                pool.submit(ready)

    def _pool(self) -> ProcessPoolExecutor:
        with self._lock:
            if self._closed:
                raise RuntimeError("the job workers are shut down")
            if self._processes is None:
                self._processes = ProcessPoolExecutor(
                    1,
                    mp_context=multiprocessing.get_context("spawn"),
                    initializer=worker_started,
                    initargs=(os.getpid(),),
                )
            return self._processes

    async def shutdown(self) -> None:
        """Stop the validation process at once (whatever it runs belongs to a cancelled job), wait for
        running thread calls to end (cancelled awaits do not stop a thread), then stop."""
        with self._lock:
            self._closed = True
            pool, self._processes = self._processes, None
        if pool is not None:
            await asyncio.to_thread(_stop_processes, pool)
        await asyncio.to_thread(self._check.shutdown, True, cancel_futures=True)
        await asyncio.to_thread(self._work.shutdown, True, cancel_futures=True)
        await asyncio.to_thread(self._queue.shutdown, True, cancel_futures=True)


def _stop_processes(pool: ProcessPoolExecutor) -> None:
    # ProcessPoolExecutor (before Python 3.14) cannot stop a running call: end its worker, then
    # let the executor notice and join its own thread.
    workers = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for worker in workers:
        if worker.is_alive():
            worker.terminate()
    pool.shutdown(wait=True)
    for worker in workers:
        worker.join()


PARENT_CHECK = 0.5  # s between the validation process's looks at whether the gateway still runs


@contextmanager
def interrupts_held() -> Iterator[None]:
    """SIGINT blocked in this thread meanwhile: a process spawned now starts with it blocked.

    A SIGINT that arrives meanwhile is not lost: it waits, or goes to a thread that
    does not block it, and Python handles it in the main thread as always.
    """
    if not hasattr(signal, "pthread_sigmask"):  # pragma: no cover - Windows has no signal masks
        yield
        return
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def worker_started(parent: int) -> None:
    """In the validation process, before any call: ignore SIGINT, then follow the parent.

    The gateway stops this process at shutdown; a Ctrl-C, which reaches the whole
    process group, must not stop it first with a traceback.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # a pending one is dropped: ignored
    follow_parent(parent)


def follow_parent(parent: int) -> None:
    """In the validation process: exit when the gateway that started it is gone.

    A gateway killed with SIGKILL (the OOM killer, a service manager's last resort)
    cannot stop its worker, and the worker would wait for work forever, one orphan
    per restart. The worker's parent then becomes init (or a subreaper).
    """

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_CHECK)
        os._exit(0)

    threading.Thread(target=watch, name="follow-parent", daemon=True).start()

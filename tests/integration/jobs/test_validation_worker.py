"""The validation process does not outlive a gateway killed with SIGKILL (no orphan per restart), and a
SIGINT (Ctrl-C reaches the whole process group) does not stop it: the gateway does."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

from tests.waiting import wait_until_sync

PARENT = """
import asyncio, os, sys
from gateway.jobs.threads import JobThreads

async def main():
    threads = JobThreads()
    worker = await threads.process(os.getpid)
    print(worker, flush=True)
    await asyncio.sleep(3600)

if __name__ == "__main__":
    asyncio.run(main())
"""


INTERRUPTED = """
import asyncio, os, sys
from gateway.jobs.threads import JobThreads

async def main():
    threads = JobThreads()
    print(await threads.process(os.getpid), flush=True)
    await asyncio.to_thread(sys.stdin.readline)  # the test interrupts the worker meanwhile
    print(await threads.process(os.getpid), flush=True)
    await threads.shutdown()

if __name__ == "__main__":
    asyncio.run(main())
"""


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie is gone for our purpose (its parent, init, reaps it)
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ", 1)[1][0] != "Z"
    except OSError:
        return True


def test_the_validation_process_exits_when_its_gateway_is_killed() -> None:
    parent = subprocess.Popen([sys.executable, "-c", PARENT], stdout=subprocess.PIPE, text=True)
    try:
        worker = int(parent.stdout.readline())  # type: ignore[union-attr]
        assert worker != parent.pid and alive(worker)
        parent.send_signal(signal.SIGKILL)
        parent.wait(timeout=10)
        wait_until_sync(lambda: not alive(worker), timeout=10, message="the orphaned worker to exit")
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait()


def test_the_validation_process_ignores_sigint() -> None:
    parent = subprocess.Popen(
        [sys.executable, "-c", INTERRUPTED],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        worker = int(parent.stdout.readline())  # type: ignore[union-attr]
        os.kill(worker, signal.SIGINT)
        parent.stdin.write("go on\n")  # type: ignore[union-attr]
        parent.stdin.flush()  # type: ignore[union-attr]
        assert parent.stdout.readline().strip() == str(worker)  # type: ignore[union-attr]  # the same process answers
        assert parent.wait(timeout=30) == 0
        assert "Traceback" not in parent.stderr.read()  # type: ignore[union-attr]
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait()

"""Ctrl-C at a terminal reaches the whole process group: the gateway and its validation process.

The gateway shuts down cleanly; the validation process ignores SIGINT and is stopped by the gateway,
so nothing prints a KeyboardInterrupt traceback (as `make demo` used to, from the worker).
"""

from __future__ import annotations

import ftplib
import os
import signal
import subprocess
from pathlib import Path

import psutil

from gateway.jobs.validation import compiled
from tests.integration.drills.processes import BIN, clean_env, gateway_file, port_open
from tests.integration.jobs.conftest import PASSWORD, PASSWORD_HASH, USER, mapping_text
from tests.waiting import free_port, wait_until_sync


def validation_process(gateway: psutil.Process) -> psutil.Process | None:
    """The gateway's validation process (multiprocessing's spawn), once it has started."""
    for child in gateway.children():
        try:
            if any("spawn_main" in part for part in child.cmdline()):
                return child
        except psutil.NoSuchProcess:
            continue
    return None


def has_loaded_the_validator(worker: psutil.Process) -> bool:
    """True once the worker has imported validation, with its compiled reader (the warm-up call ran)."""
    try:
        return any("_plain" in m.path for m in worker.memory_maps(grouped=True))
    except (psutil.NoSuchProcess, psutil.AccessDenied):
        return False


def test_ctrl_c_stops_the_gateway_and_its_validation_process_without_a_traceback(tmp_path: Path) -> None:
    inbox_port = free_port()
    (tmp_path / "laser.yaml").write_text(mapping_text("laser", free_port(), opcua_port=free_port()))
    config = gateway_file(
        tmp_path,
        ["laser.yaml"],
        opcua_port=free_port(),
        inbox_port=inbox_port,
        inbox={"accounts": [{"user": USER, "password_hash": PASSWORD_HASH}]},
    )
    out, err = tmp_path / "stdout.log", tmp_path / "stderr.log"
    with out.open("wb") as stdout, err.open("wb") as stderr:
        proc = subprocess.Popen(
            [str(BIN / "cnc-gateway"), "run", str(config)],
            stdout=stdout,
            stderr=stderr,
            cwd=tmp_path,
            env=clean_env(),
            start_new_session=True,  # its own process group, as a terminal's job is
        )
    try:
        wait_until_sync(
            lambda: port_open(inbox_port) or proc.poll() is not None,
            timeout=60,
            message="the gateway's inbox to listen",
        )
        assert proc.poll() is None, err.read_text()
        with ftplib.FTP() as ftp:  # a login starts the validation process (JobThreads.warm)
            ftp.connect("127.0.0.1", inbox_port, timeout=10)
            ftp.login(USER, PASSWORD)
            ftp.quit()
        gateway = psutil.Process(proc.pid)
        wait_until_sync(
            lambda: validation_process(gateway) is not None,
            timeout=60,
            message="the validation process to start",
        )
        worker = validation_process(gateway)
        assert worker is not None
        if compiled.plain is not None:
            wait_until_sync(
                lambda: has_loaded_the_validator(worker),
                timeout=60,
                message="the validation process to be ready",
            )
        os.killpg(proc.pid, signal.SIGINT)  # what Ctrl-C does
        assert proc.wait(timeout=60) == 0
        wait_until_sync(
            lambda: not worker.is_running() or worker.status() == psutil.STATUS_ZOMBIE,
            timeout=30,
            message="the validation process to end",
        )
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    errors = err.read_text(errors="replace") + out.read_text(errors="replace")
    assert "SIGINT received, shutting down" in errors  # the gateway's own clean stop
    # An interrupted child starts with "Process SpawnProcess-1:", then the traceback (if it is not
    # stopped first); neither may appear.
    for sign in ("Traceback", "KeyboardInterrupt", "Process SpawnProcess"):
        assert sign not in errors, errors

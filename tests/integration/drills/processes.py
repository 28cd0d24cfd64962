"""The gateway and the simulator as processes of their own, so a drill can SIGKILL them and read their memory.

Both run from their console scripts in the virtualenv (`cnc-gateway run`,
`cnc-simulator`), on free loopback ports, with their output appended to a log
file that a failing drill prints the tail of.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import yaml

ROOT = Path(__file__).resolve().parents[3]
BIN = Path(sys.executable).parent
MIB = 1024 * 1024


def port_open(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.2)
        return s.connect_ex(("127.0.0.1", port)) == 0


def clean_env() -> dict[str, str]:
    """The test's environment without proxies (paho and curl honour them) and with unbuffered output."""
    env = {k: v for k, v in os.environ.items() if k.lower() not in ("http_proxy", "https_proxy", "all_proxy")}
    env["PYTHONUNBUFFERED"] = "1"
    return env


class Process:
    """One child process with its log; can be killed and started again with the same command."""

    def __init__(self, name: str, argv: list[str], log: Path, cwd: Path) -> None:
        self.name = name
        self.argv = argv
        self.log = log
        self.cwd = cwd
        self.proc: subprocess.Popen[bytes] | None = None
        self.starts = 0

    def start(self) -> Process:
        assert self.proc is None or self.proc.poll() is not None, f"{self.name} is already running"
        with self.log.open("ab") as out:
            out.write(f"\n===== start {self.starts + 1}: {' '.join(self.argv)}\n".encode())
            out.flush()
            self.proc = subprocess.Popen(
                self.argv, stdout=out, stderr=subprocess.STDOUT, cwd=self.cwd, env=clean_env()
            )
        self.starts += 1
        return self

    @property
    def pid(self) -> int:
        assert self.proc is not None
        return self.proc.pid

    @property
    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def kill(self) -> None:
        """SIGKILL, as a power cut or the OOM killer would, and reap it."""
        if self.alive:
            assert self.proc is not None
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(timeout=30)

    def stop(self, timeout: float = 15.0) -> int | None:
        """SIGTERM and wait; SIGKILL if it does not end in time. Returns the exit code."""
        if self.proc is None:
            return None
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=30)
        return self.proc.returncode

    def rss(self) -> int:
        """Resident set size in bytes, from /proc/<pid>/status (VmRSS)."""
        for line in Path(f"/proc/{self.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
        raise RuntimeError(f"no VmRSS for {self.name} (pid {self.pid})")

    def tail(self, chars: int = 4000) -> str:
        try:
            return self.log.read_text(errors="replace")[-chars:]
        except FileNotFoundError:
            return ""


def gateway(directory: Path, gateway_file: Path) -> Process:
    return Process(
        "gateway", [str(BIN / "cnc-gateway"), "run", str(gateway_file)], directory / "gateway.log", directory
    )


def simulator(directory: Path, opcua_port: int, ftp_port: int, *args: str) -> Process:
    argv = [
        str(BIN / "cnc-simulator"), "--opcua-port", str(opcua_port), "--ftp-port", str(ftp_port),
        "--store", str(directory / "store"), "--log-level", "warning", *args,
    ]  # fmt: skip
    (directory / "store").mkdir(parents=True, exist_ok=True)
    return Process("simulator", argv, directory / "simulator.log", directory)


# --- configuration files ---------------------------------------------------------------------------


def laser_sim(sim_port: int, **changes: Any) -> dict[str, Any]:
    """The shipped mappings/laser-sim.yaml as data, pointed at a simulator on `sim_port`.

    Reconnects are quicker than shipped (0.2 s to 2 s rather than 0.5 s to 10 s) so that a
    controller that comes back is Good again within seconds; jobs and COPYDATA are left out
    unless `changes` puts them back. Top-level keys in `changes` replace the file's.
    """
    data = yaml.safe_load((ROOT / "mappings" / "laser-sim.yaml").read_text())
    data["driver"]["endpoint"] = f"opc.tcp://127.0.0.1:{sim_port}"
    data["driver"]["watchdog_interval"] = 0.5
    data["driver"]["reconnect"] = {"initial": 0.2, "max": 2.0, "factor": 2}
    data.pop("jobs", None)
    data.pop("copydata", None)
    data.update(changes)
    return data


def chiller_sim(modbus_port: int) -> dict[str, Any]:
    """The shipped mappings/chiller-sim.yaml as data, pointed at a simulator's Modbus face on `modbus_port`,
    with the drills' quick reconnects."""
    data = yaml.safe_load((ROOT / "mappings" / "chiller-sim.yaml").read_text())
    data["driver"].update(
        host="127.0.0.1", port=modbus_port, reconnect={"initial": 0.2, "max": 2.0, "factor": 2}
    )
    return data


def write_yaml(path: Path, data: Any) -> Path:
    path.write_text(yaml.safe_dump(data, sort_keys=False, allow_unicode=True), encoding="utf-8")
    return path


def gateway_file(
    directory: Path,
    mappings: list[str],
    *,
    opcua_port: int,
    inbox_port: int,
    mqtt: dict[str, Any] | None = None,
    inbox: dict[str, Any] | None = None,
) -> Path:
    data: dict[str, Any] = {
        "opcua": {"endpoint": f"opc.tcp://127.0.0.1:{opcua_port}/cnc-gateway", "security": ["None"]},
        "state_dir": "state",
        "log_level": "info",
        "machines": mappings,
        "inbox": {"host": "127.0.0.1", "port": inbox_port, **(inbox or {})},
    }
    if mqtt is not None:
        data["mqtt"] = mqtt
    return write_yaml(directory / "gateway.yaml", data)


def wait_for_port(process: Process, port: int, timeout: float = 30.0) -> None:
    """Block until `process` listens on `port` (fail early, with its log, if it died)."""
    deadline = time.monotonic() + timeout
    while not port_open(port):
        if not process.alive:
            raise AssertionError(f"{process.name} exited before listening on {port}:\n{process.tail()}")
        if time.monotonic() > deadline:
            raise AssertionError(
                f"{process.name} did not listen on {port} within {timeout} s:\n{process.tail()}"
            )
        time.sleep(0.02)

"""The console scripts as a user runs them: real processes, real ports, real signals."""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from asyncua import ua

from gateway.config.loader import load_mapping
from simulator.runner import Simulator
from tests.opcua_client import Client
from tests.waiting import free_port, wait_until

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent


def spawn(*args: str, env: dict[str, str] | None = None, cwd: Path = ROOT) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [str(BIN / args[0]), *args[1:]],
        cwd=cwd,
        env={**os.environ, **(env or {})},
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


@pytest.fixture
def processes() -> Iterator[list[subprocess.Popen[str]]]:
    procs: list[subprocess.Popen[str]] = []
    yield procs
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=10)


def stop(proc: subprocess.Popen[str], sig: signal.Signals = signal.SIGINT) -> tuple[int, str, str]:
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=15)
    return proc.returncode, out, err


async def read_value(endpoint: str, nodeid: str) -> ua.DataValue | None:
    try:
        async with Client(endpoint, timeout=2) as client:
            return await client.get_node(nodeid).read_data_value(raise_on_bad_status=False)
    except (OSError, TimeoutError, ua.UaError):
        return None


async def test_run_serves_bad_values_while_the_controller_is_down_and_stops_cleanly(
    tmp_path: Path, processes: list[subprocess.Popen[str]]
) -> None:
    gw_port, sim_port = free_port(), free_port()
    gateway_file = tmp_path / "gateway.yaml"
    gateway_file.write_text(
        f"opcua: {{endpoint: 'opc.tcp://127.0.0.1:{gw_port}/cnc-gateway'}}\n"
        f"state_dir: state\ninbox: {{port: {free_port()}}}\n"
        f"machines: [{ROOT / 'mappings' / 'laser-sim.yaml'}]\n"
    )
    proc = spawn(
        "cnc-gateway",
        "run",
        str(gateway_file),
        env={"LASER_SIM_ENDPOINT": f"opc.tcp://127.0.0.1:{sim_port}", "LASER_SIM_COPYDATA_PORT": "0"},
    )
    processes.append(proc)
    endpoint = f"opc.tcp://127.0.0.1:{gw_port}/cnc-gateway"

    async def bad_position() -> bool:
        dv = await read_value(endpoint, "ns=2;s=laser-sim/Axes/X/Position")
        return dv is not None and dv.StatusCode is not None and dv.StatusCode.is_bad()

    await wait_until(bad_position, timeout=20, message="gateway serving X position as Bad")
    state = await read_value(endpoint, "ns=2;s=laser-sim/Status/State")
    assert state is not None and state.Value.Value in ("disconnected", "connecting")
    assert proc.poll() is None, "the gateway must keep running while the controller is down"

    async with Simulator(opcua_port=sim_port, ftp_port=free_port(), speed=10, store=tmp_path / "store"):

        async def good_position() -> bool:
            dv = await read_value(endpoint, "ns=2;s=laser-sim/Axes/X/Position")
            return dv is not None and dv.StatusCode.is_good()

        await wait_until(good_position, timeout=20, message="X position Good once the simulator is up")

    code, _, err = stop(proc)
    assert code == 0, err
    assert "Traceback" not in err
    assert "shutting down" in err


def test_run_refuses_a_broken_mapping_without_starting(tmp_path: Path) -> None:
    proc = subprocess.run(
        [str(BIN / "cnc-gateway"), "run", str(ROOT / "tests/corpus/mappings/many-errors.yaml")],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert proc.returncode == 2
    assert "6 errors; nothing was started." in proc.stderr


def test_run_says_in_one_line_that_the_lease_database_is_out_of_reach(tmp_path: Path) -> None:
    closed = free_port()  # nothing listens there
    (tmp_path / "gateway.yaml").write_text(
        f"machines: [{ROOT / 'mappings/laser-sim.yaml'}]\nshard: lease\n"
        f"queue: postgresql://gateway@127.0.0.1:{closed}/cnc\nstate_dir: state\nhttp: null\n"
        f"opcua: {{endpoint: 'opc.tcp://127.0.0.1:{free_port()}/cnc-gateway', security: [None]}}\n"
        f"inbox: {{port: {free_port()}}}\n"
    )
    proc = subprocess.run(
        [str(BIN / "cnc-gateway"), "run", str(tmp_path / "gateway.yaml")],
        capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert proc.returncode == 1, proc.stderr[-2000:]
    assert (
        f"cannot start: cannot reach the lease table at postgresql://gateway@127.0.0.1:{closed}/cnc"
        in proc.stderr
    )
    assert "Traceback" not in proc.stderr


async def test_check_prints_the_tree_with_type_unit_and_access_the_commands_and_copydata_targets() -> None:
    proc = subprocess.run(
        [str(BIN / "cnc-gateway"), "check", str(ROOT / "mappings/laser-sim.yaml")],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    override = next(line for line in lines if line.strip().startswith("Override"))
    assert override.split()[1:4] == ["UInt16", "%", "readwrite"]
    assert "copydata 6" in override and "role" not in override  # no users: roles are not shown on variables
    assert lines[-1] == (
        "no users: OPC UA clients are anonymous, with role viewer (access.anonymous); "
        "writes and commands the mappings open to MQTT act as admin; COPYDATA writes as nobody: refused "
        "(access.copydata_role)"
    )
    command = next(line for line in lines if line.strip().startswith("select-program"))
    assert command.split() == [
        "select-program(name:",
        "String)",
        "operator",
        "Machine/State",
        "is",
        "Idle",
        "or",
        "Alarm",
    ]
    assert next(line for line in lines if line.strip().startswith("stop ")).split() == [
        "stop",
        "operator",
        "any",
        "state",
    ]
    nesting = next(line for line in lines if line.strip().startswith("nesting"))
    assert nesting.split()[1] == "tcp-server" and "ids 1-11, 14-16 (14 variables)" in nesting
    assert "connected 100" in nesting and "accepts writes" not in nesting  # on with a copydata_role only


async def test_demo_runs_the_simulator_and_keeps_a_program_running(
    tmp_path: Path, processes: list[subprocess.Popen[str]]
) -> None:
    gw_port, sim_port, ftp_port = free_port(), free_port(), free_port()
    proc = spawn(
        "cnc-gateway",
        "demo",
        "--opcua-port",
        str(gw_port),
        "--sim-opcua-port",
        str(sim_port),
        "--sim-ftp-port",
        str(ftp_port),
        "--speed",
        "20",
        "--state-dir",
        str(tmp_path / "state"),
        *demo_extra_args(),
    )
    processes.append(proc)
    endpoint = f"opc.tcp://127.0.0.1:{gw_port}/cnc-gateway"

    async def running() -> bool:
        dv = await read_value(endpoint, "ns=2;s=laser-sim/Machine/StateText")
        return dv is not None and dv.StatusCode.is_good() and dv.Value.Value == "Running"

    await wait_until(running, timeout=30, message="the demo program to run")
    first = await read_value(endpoint, "ns=2;s=laser-sim/Program/Block")

    async def advanced() -> bool:
        now = await read_value(endpoint, "ns=2;s=laser-sim/Program/Block")
        return now is not None and first is not None and now.Value.Value != first.Value.Value

    await wait_until(advanced, timeout=20, message="the program's block number to advance")

    # The outage drill the banner offers: SIGUSR1 stops the in-process simulator, a second one restarts it.
    async def position_status() -> ua.StatusCode | None:
        dv = await read_value(endpoint, "ns=2;s=laser-sim/Axes/X/Position")
        return None if dv is None else dv.StatusCode

    proc.send_signal(signal.SIGUSR1)
    await wait_until(
        lambda: _is(position_status(), bad=True), timeout=10, message="X Bad after the simulator stopped"
    )
    proc.send_signal(signal.SIGUSR1)
    await wait_until(
        lambda: _is(position_status(), bad=False), timeout=15, message="X Good after it restarted"
    )
    code, out, err = stop(proc, signal.SIGTERM)
    assert code == 0, err
    assert "Traceback" not in err
    assert f"opc.tcp://127.0.0.1:{gw_port}/cnc-gateway" in out


async def _is(status: Any, *, bad: bool) -> bool:
    code = await status
    return code is not None and (code.is_bad() if bad else code.is_good())


def demo_extra_args() -> list[str]:
    """Ports of the demo's other services, so a test never touches the defaults."""
    from gateway.cli.main import build_parser

    parser = build_parser()
    demo = parser._subparsers._group_actions[0].choices["demo"]  # type: ignore[union-attr]
    options = {opt for action in demo._actions for opt in action.option_strings}
    extra: list[str] = []
    for flag in (
        "--mqtt-port",
        "--inbox-port",
        "--copydata-port",
        "--mtconnect-port",
        "--sim-dnc-port",
        "--sim-dnc-opcua-port",
        "--sim-dnc-ftp-port",
        "--sim-focas-port",
    ):
        if flag in options:
            extra += [flag, str(free_port())]
    return extra


async def test_discover_writes_a_mapping_that_loads(tmp_path: Path) -> None:
    sim_port = free_port()
    out = tmp_path / "discovered.yaml"
    async with Simulator(opcua_port=sim_port, ftp_port=free_port(), store=tmp_path / "store"):
        # in a thread: the simulator shares this event loop and must keep answering
        proc = await asyncio.to_thread(
            subprocess.run,
            [
                str(BIN / "cnc-gateway"),
                "discover",
                f"opc.tcp://127.0.0.1:{sim_port}",
                "--machine",
                "press-3",
                "-o",
                str(out),
            ],
            capture_output=True,
            text=True,
            timeout=60,
        )
    assert proc.returncode == 0, proc.stderr
    mapping = load_mapping(out)
    assert mapping.machine == "press-3"
    sources = {v.source: v for v in mapping.variables}
    act = next(v for s, v in sources.items() if s.endswith("gAxis[0].ActPos"))
    assert str(act.type) == "Double" and act.access == "read"
    override = next(v for s, v in sources.items() if s.endswith("gFeed.Override"))
    assert str(override.type) == "UInt16" and override.access == "readwrite"
    table = next(v for s, v in sources.items() if s.endswith("::Laser:powerTable"))
    assert str(table.type) == "Double[]"


def test_discover_reports_an_unreachable_controller_in_one_line() -> None:
    proc = subprocess.run(
        [str(BIN / "cnc-gateway"), "discover", f"opc.tcp://127.0.0.1:{free_port()}", "--timeout", "2"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert proc.returncode == 1
    assert proc.stderr.startswith("error:") and "Traceback" not in proc.stderr

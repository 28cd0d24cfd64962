"""`cnc-gateway demo` (what `make demo` runs): the simulator, the laser-sim mapping, live values.

The simulator runs in-process unless one is already listening on its port, in
which case the demo uses that one. A small driver keeps a program running by
writing the simulator's command variables through the gateway's own write path,
so the demo also shows that writes reach the controller. Pressing Enter (or
sending SIGUSR1) stops and restarts the in-process simulator, to rehearse a
controller outage: values turn Bad within seconds and Good again after.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import signal
import socket
import sys
from pathlib import Path

from gateway.app import Gateway, run_until_signalled
from gateway.cli.check import report_config_error
from gateway.config.gateway import GatewayConfig, OpcUaServerConfig
from gateway.config.loader import Config, load
from gateway.config.mapping import MachineMapping
from gateway.errors import ConfigError, SinkError, WriteError
from gateway.logconfig import configure
from gateway.model.tree import Machine, WriteContext

log = logging.getLogger("gateway.demo")

DEMO_PROGRAM = "demo.nc"
STATE_IDLE, STATE_ALARM = 0, 3


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="run the simulator and the gateway together on the default ports")
    p.add_argument("--mapping", type=Path, default=None, help="default: mappings/laser-sim.yaml")
    p.add_argument("--opcua-port", type=int, default=4840, help="gateway OPC UA port (default 4840)")
    p.add_argument("--sim-opcua-port", type=int, default=4841, help="simulator OPC UA port (default 4841)")
    p.add_argument("--sim-ftp-port", type=int, default=2122, help="simulator FTP port (default 2122)")
    p.add_argument("--speed", type=float, default=1.0, help="simulator speed factor (default 1)")
    p.add_argument("--state-dir", type=Path, default=Path("state/demo"))
    p.add_argument("--log-level", choices=["debug", "info", "warning", "error"], default="info")
    p.set_defaults(handler=handle)


def find_mapping(given: Path | None) -> Path:
    if given is not None:
        return given
    for base in (Path.cwd(), Path(__file__).resolve().parents[2]):
        candidate = base / "mappings" / "laser-sim.yaml"
        if candidate.exists():
            return candidate
    return Path("mappings/laser-sim.yaml")


def port_in_use(host: str, port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.settimeout(0.5)
        return s.connect_ex((host, port)) == 0


def handle(args: argparse.Namespace) -> int:
    configure(args.log_level)
    try:
        base = load([find_mapping(args.mapping)])
    except ConfigError as exc:
        report_config_error(exc)
        return 2
    mapping = base.machines[0]
    endpoint = f"opc.tcp://127.0.0.1:{args.sim_opcua_port}"
    mapping = mapping.model_copy(update={"driver": mapping.driver.model_copy(update={"endpoint": endpoint})})
    gateway = GatewayConfig(
        opcua=OpcUaServerConfig(endpoint=f"opc.tcp://0.0.0.0:{args.opcua_port}/cnc-gateway"),
        state_dir=str(args.state_dir),
    )
    config = Config(gateway, (mapping,), Path.cwd(), base.files)
    try:
        asyncio.run(run_until_signalled(demo(config, args)))
    except SinkError as exc:
        log.error("cannot start: %s", exc)
        return 1
    return 0


async def demo(config: Config, args: argparse.Namespace) -> None:
    mapping = config.machines[0]
    external = port_in_use("127.0.0.1", args.sim_opcua_port)
    toggle = asyncio.Event()
    async with Gateway(config) as gw:
        machine = gw.tree.machines[mapping.machine]
        tasks: list[tuple[str, object]] = [("demo:driver", lambda: keep_program_running(machine))]
        if external:
            log.info("a simulator is already listening on port %d: using it", args.sim_opcua_port)
        else:
            tasks.append(("demo:simulator", lambda: simulator_loop(config, args, toggle)))
            _install_toggle(toggle)
        print_banner(gw, mapping, args, external)
        await gw.run(*tasks)  # type: ignore[arg-type]


async def simulator_loop(config: Config, args: argparse.Namespace, toggle: asyncio.Event) -> None:
    """Run the in-process simulator; each toggle stops it or starts it again."""
    from simulator.runner import Simulator

    store = config.state_dir / "simulator-store"
    store.mkdir(parents=True, exist_ok=True)
    while True:
        async with Simulator(
            opcua_port=args.sim_opcua_port, ftp_port=args.sim_ftp_port, speed=args.speed, store=store
        ):
            log.info("simulator running (OPC UA %d, FTP %d)", args.sim_opcua_port, args.sim_ftp_port)
            await toggle.wait()
            toggle.clear()
        log.warning("simulator STOPPED: values go Bad within seconds. Press Enter (or kill -USR1) to start it again.")
        await toggle.wait()
        toggle.clear()


def _install_toggle(toggle: asyncio.Event) -> None:
    loop = asyncio.get_running_loop()
    with contextlib.suppress(NotImplementedError, RuntimeError, AttributeError):
        loop.add_signal_handler(signal.SIGUSR1, toggle.set)
    if sys.stdin is not None and sys.stdin.isatty():

        def on_input() -> None:
            if not sys.stdin.readline():
                loop.remove_reader(sys.stdin)
                return
            toggle.set()

        with contextlib.suppress(NotImplementedError, OSError, ValueError):
            loop.add_reader(sys.stdin, on_input)


async def keep_program_running(machine: Machine) -> None:
    """Select and start the demo program whenever the machine is idle; reset alarms."""
    ctx = WriteContext("demo")
    state = machine.nodes["Machine/State"]
    name = machine.nodes["Program/Name"]
    while True:
        await asyncio.sleep(1.0)
        if not machine.status.is_connected or not state.sample.good:
            continue
        try:
            if state.sample.value == STATE_ALARM:
                log.info("demo: machine in alarm, resetting")
                await machine.write("Control/Reset", True, ctx)
            elif state.sample.value == STATE_IDLE:
                if name.sample.value != DEMO_PROGRAM:
                    await machine.write("Control/SelectProgram", DEMO_PROGRAM, ctx)
                await machine.write("Control/Start", True, ctx)
                log.info("demo: started %s", DEMO_PROGRAM)
        except WriteError as exc:
            log.info("demo: %s (%s); will retry", exc.reason, exc.status)


def print_banner(gw: Gateway, mapping: MachineMapping, args: argparse.Namespace, external: bool) -> None:
    opcua = gw.sink("opcua")
    endpoint = getattr(opcua, "endpoint", f"opc.tcp://127.0.0.1:{args.opcua_port}/cnc-gateway")
    lines = [
        "",
        "cnc-gateway demo",
        f"  OPC UA server    {endpoint.replace('0.0.0.0', '127.0.0.1')}  (security None, anonymous)",
        f"  browse           Objects/Machines/{mapping.machine}/Axes/X/Position, Feed/Override (writable), Status/...",
        f"  node ids         ns=2;s={mapping.machine}/Axes/X/Position",
        f"  simulator        {mapping.driver.endpoint} (OPC UA), ftp://127.0.0.1:{args.sim_ftp_port}/DATA/Programs "
        + ("(already running)" if external else "(in-process)"),
    ]
    if not external:
        lines.append("  outage drill     press Enter (or kill -USR1 <pid>) to stop the simulator, again to restart it")
    lines += ["  stop             Ctrl-C", ""]
    print("\n".join(lines), flush=True)

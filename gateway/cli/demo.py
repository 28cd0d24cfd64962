"""`cnc-gateway demo` (what `make demo` runs): the simulator, the laser-sim mapping, live values.

The simulator runs in-process unless one is already listening on its port, in
which case the demo uses that one. A small driver (demo_driver.py) keeps a program running
by writing the simulator's command variables through the gateway's own write path,
so the demo also shows that writes reach the controller; it steps aside while
someone else commands the machine. Pressing Enter (or
sending SIGUSR1) stops and restarts the in-process simulator, to rehearse a
controller outage: values turn Bad within seconds and Good again after.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import os
import signal
import socket
import sys
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import Any

from gateway.app import Gateway, run_until_signalled
from gateway.auth.passwords import hash_password
from gateway.cli import demo_focas, demo_plc
from gateway.cli.check import report_config_error
from gateway.cli.demo_dnc import DRIP_NAME, keep_dripping, point_at, punch_once
from gateway.cli.demo_dnc import simulator as dnc_simulator
from gateway.cli.demo_driver import keep_program_running
from gateway.config.gateway import GatewayConfig
from gateway.config.jobs import FtpAccount, InboxConfig
from gateway.config.loader import Config, load
from gateway.config.mapping import MachineMapping
from gateway.errors import ConfigError, SinkError
from gateway.logconfig import configure
from gateway.settings.access import AccessConfig, UserConfig
from gateway.sinks.mqtt.config import MachineMqtt, MqttConfig
from gateway.sinks.mtconnect.config import AgentConfig
from gateway.sinks.opcua.config import OpcUaServerConfig
from gateway.sinks.sparkplug.config import SparkplugConfig
from gateway.sinks.web.config import HttpConfig
from gateway.sources.base import settings_of
from gateway.sources.opcua.config import OpcUaDriver
from gateway.transports.dnc.config import ControllerSerial

log = logging.getLogger("gateway.demo")

DEMO_INBOX_USER = "nesting"
DEMO_INBOX_PASSWORD = "nesting"  # a demo-only default, printed in the banner
DEMO_INBOX_PASSWORD_ENV = "CNC_DEMO_INBOX_PASSWORD"
DEMO_USERS = ("viewer", "operator", "engineer", "admin")  # logins (OPC UA, web console), role = name
DEMO_PASSWORD_ENV = "CNC_DEMO_PASSWORD"  # their password; default: the user name


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("demo", help="run the simulator and the gateway together on the default ports")
    p.add_argument("--mapping", type=Path, default=None, help="default: mappings/laser-sim.yaml")
    p.add_argument("--opcua-port", type=int, default=4840, help="gateway OPC UA port (default 4840)")
    p.add_argument("--sim-opcua-port", type=int, default=4841, help="simulator OPC UA port (default 4841)")
    p.add_argument("--sim-ftp-port", type=int, default=2122, help="simulator FTP port (default 2122)")
    p.add_argument("--inbox-port", type=int, default=2121, help="FTP job inbox port (default 2121)")
    p.add_argument("--inbox-host", default="127.0.0.1", help="FTP job inbox address (default 127.0.0.1)")
    p.add_argument(
        "--copydata-port",
        type=int,
        default=5020,
        help="port of the mapping's COPYDATA tcp-server target (default 5020)",
    )
    p.add_argument(
        "--mtconnect-port", type=_port_or_off, default=5000, help="MTConnect agent port (default 5000; 'off')"
    )
    p.add_argument(
        "--sim-shdr-port", type=_port_or_off, default=_sim_shdr_default(),
        help="simulator's MTConnect adapter (SHDR) port (default $CNC_SIM_SHDR_PORT or 7878; 'off')",
    )  # fmt: skip
    p.add_argument(
        "--http-port",
        type=int,
        default=8080,
        help="web console, REST API and /metrics (default 8080; 0: off)",
    )
    p.add_argument("--http-host", default="127.0.0.1", help="web console address (default 127.0.0.1)")
    p.add_argument("--speed", type=float, default=1.0, help="simulator speed factor (default 1)")
    p.add_argument("--state-dir", type=Path, default=Path("state/demo"))
    p.add_argument("--mqtt-host", default="127.0.0.1", help="MQTT broker (default 127.0.0.1)")
    p.add_argument(
        "--mqtt-port",
        type=int,
        default=1883,
        help="MQTT broker port (default 1883); when nothing "
        "answers there, the demo starts an embedded broker on it",
    )
    p.add_argument("--no-mqtt", action="store_true", help="do not publish to MQTT (nor Sparkplug)")
    p.add_argument(
        "--no-sparkplug", action="store_true", help="do not publish Sparkplug B beside the JSON topics"
    )
    p.add_argument("--sparkplug-group", default="cnc", help="Sparkplug group id (default cnc)")
    p.add_argument(
        "--sparkplug-edge-node", default="cnc-gateway", help="Sparkplug edge node id (default cnc-gateway)"
    )
    p.add_argument(
        "--sparkplug-primary-host",
        default=None,
        help="wait for this primary host's STATE before the births (default: publish at once)",
    )
    p.add_argument(
        "--sim-dnc-port", type=_port_or_off, default=4001,
        help="the serial machine's device server (its simulator's DNC face, socket://; default 4001; "
        "'off': no serial machine)",
    )  # fmt: skip
    p.add_argument(
        "--sim-dnc-opcua-port", type=int, default=4843, help="the serial machine simulator's OPC UA port"
    )
    p.add_argument(
        "--sim-dnc-ftp-port", type=int, default=2123, help="the serial machine simulator's FTP port"
    )
    demo_focas.add_arguments(p, _port_or_off)
    demo_plc.add_arguments(p)
    p.add_argument("--log-level", choices=["debug", "info", "warning", "error"], default="info")
    p.set_defaults(handler=handle)


def _port_or_off(text: str) -> int | None:
    if text.strip().lower() in ("off", "none", "no"):
        return None
    try:
        port = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a port number (or 'off')") from None
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"port {port} is outside 0..65535")
    return port


def _sim_shdr_default() -> int | None:
    try:
        return _port_or_off(os.environ.get("CNC_SIM_SHDR_PORT", "7878"))
    except argparse.ArgumentTypeError:
        return 7878


def find_mapping(given: Path | None, name: str = "laser-sim.yaml") -> Path:
    if given is not None:
        return given
    for base in (Path.cwd(), Path(__file__).resolve().parents[2]):
        candidate = base / "mappings" / name
        if candidate.exists():
            return candidate
    return Path("mappings") / name


def port_in_use(host: str, port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.settimeout(0.5)
        return s.connect_ex((host, port)) == 0


def handle(args: argparse.Namespace) -> int:
    configure(args.log_level)
    files = [find_mapping(args.mapping)]
    if args.sim_dnc_port is not None:
        files.append(find_mapping(None, "laser-dnc.yaml"))
    if args.sim_focas_port is not None:
        files.append(find_mapping(None, demo_focas.MAPPING))
    files += [find_mapping(None, name) for name in demo_plc.mapping_names(args)]
    try:
        base = load(files)
    except ConfigError as exc:
        report_config_error(exc)
        return 2
    mapping = base.machines[0]
    endpoint = f"opc.tcp://127.0.0.1:{args.sim_opcua_port}"
    driver = settings_of(mapping, OpcUaDriver).model_copy(update={"endpoint": endpoint})  # the demo machine
    mapping = mapping.model_copy(update={"driver": driver})
    if (
        mapping.mqtt is None
    ):  # the demo lets MQTT write the readwrite variables (Feed/Override…) and run commands
        mapping = mapping.model_copy(update={"mqtt": MachineMqtt(writable=True, commands=True)})
    mapping = demo_jobs(mapping, args)
    mapping = demo_copydata(mapping, args)
    machines = [mapping]
    if args.sim_dnc_port is not None:
        machines.append(
            point_at(base.machines[1], opcua_port=args.sim_dnc_opcua_port, dnc_port=args.sim_dnc_port)
        )
    if args.sim_focas_port is not None:
        machines.append(demo_focas.point_at(base.machines[len(machines)], args.sim_focas_port))
    machines += demo_plc.point(list(base.machines[len(machines) :]), args)  # the chiller, the PLC
    gateway = GatewayConfig(
        opcua=OpcUaServerConfig(endpoint=f"opc.tcp://0.0.0.0:{args.opcua_port}/cnc-gateway"),
        state_dir=str(args.state_dir),
        inbox=demo_inbox(mapping, args, [m.machine for m in machines]),
        mqtt=None if args.no_mqtt else MqttConfig(host=args.mqtt_host, port=args.mqtt_port),
        sparkplug=demo_sparkplug(args),
        mtconnect=None if args.mtconnect_port is None else AgentConfig(port=args.mtconnect_port),
        http=HttpConfig(host=args.http_host, port=args.http_port) if args.http_port else None,
        **demo_access(),
    )
    config = Config(gateway, tuple(machines), Path.cwd(), base.files)
    try:
        asyncio.run(run_until_signalled(demo(config, args)))
    except SinkError as exc:
        log.error("cannot start: %s", exc)
        return 1
    return 0


def demo_sparkplug(args: argparse.Namespace) -> SparkplugConfig | None:
    """Sparkplug B beside the JSON topics, on the same broker (over a connection of its own)."""
    if args.no_mqtt or args.no_sparkplug:
        return None
    return SparkplugConfig(
        group_id=args.sparkplug_group,
        edge_node_id=args.sparkplug_edge_node,
        primary_host_id=args.sparkplug_primary_host,
    )


def demo_access() -> dict[str, Any]:
    """Users viewer, operator and engineer (password: the user name, or CNC_DEMO_PASSWORD), so that access
    control is on: anonymous clients look, and MQTT and COPYDATA writers act as operators."""
    shared = os.environ.get(DEMO_PASSWORD_ENV)
    users = [
        UserConfig(name=name, role=name, password_hash=hash_password(shared or name)) for name in DEMO_USERS
    ]
    access = AccessConfig(anonymous="viewer", mqtt_writer_role="operator", copydata_role="operator")
    return {"users": users, "access": access}


def demo_copydata(mapping: MachineMapping, args: argparse.Namespace) -> MachineMapping:
    """The COPYDATA tcp-server target listens on the port the demo was given. The shipped mapping's also
    takes writes back (its `accept_writes` is off, for a mapping run on its own): the demo names their
    role (demo_access: operator), and the target listens where the mapping binds it (127.0.0.1 unless
    LASER_SIM_COPYDATA_BIND says otherwise); a mapping of one's own (--mapping) keeps its setting."""
    if mapping.copydata is None:
        return mapping
    update: dict[str, Any] = {"port": args.copydata_port}
    if args.mapping is None:
        update["accept_writes"] = True
    targets = [
        t.model_copy(update=update) if t.transport == "tcp-server" else t for t in mapping.copydata.targets
    ]
    return mapping.model_copy(update={"copydata": mapping.copydata.model_copy(update={"targets": targets})})


def demo_jobs(mapping: MachineMapping, args: argparse.Namespace) -> MachineMapping:
    """The job queue delivers to the simulator's FTP store, on the port the demo runs it on."""
    if mapping.jobs is None:
        return mapping
    controller = mapping.jobs.controller.model_copy(update={"port": args.sim_ftp_port})
    return mapping.model_copy(update={"jobs": mapping.jobs.model_copy(update={"controller": controller})})


def demo_inbox(
    mapping: MachineMapping, args: argparse.Namespace, machines: list[str] | None = None
) -> InboxConfig:
    """The FTP inbox, one account for the demo's machines; its password from the environment or the
    default."""
    password = os.environ.get(DEMO_INBOX_PASSWORD_ENV) or DEMO_INBOX_PASSWORD
    account = FtpAccount(
        user=DEMO_INBOX_USER, password_hash=hash_password(password), machines=machines or [mapping.machine]
    )
    return InboxConfig(host=args.inbox_host, port=args.inbox_port, accounts=[account])


async def demo(config: Config, args: argparse.Namespace) -> None:
    external = port_in_use("127.0.0.1", args.sim_opcua_port)
    toggle = asyncio.Event()
    async with contextlib.AsyncExitStack() as stack:
        broker = await _ensure_broker(config, stack)
        # The simulator first, so the gateway finds its controller at once.
        switch = None if external else await stack.enter_async_context(SimulatorSwitch(config, args, toggle))
        dnc = None
        if args.sim_dnc_port is not None and not port_in_use("127.0.0.1", args.sim_dnc_opcua_port):
            dnc = await stack.enter_async_context(
                dnc_simulator(args, config.state_dir / "simulator-dnc-store")
            )
        gw = await stack.enter_async_context(Gateway(config))
        await _run_demo(gw, config, args, switch, toggle, broker, dnc)


async def _ensure_broker(config: Config, stack: contextlib.AsyncExitStack) -> str:
    """The demo, and only the demo, starts an embedded broker when none answers on the configured port."""
    from gateway.sinks.mqtt.embedded import EmbeddedBroker, broker_reachable

    mqtt = config.gateway.mqtt
    if mqtt is None:
        return "off"
    if await asyncio.to_thread(broker_reachable, mqtt.host, mqtt.port):
        log.info("using the MQTT broker on %s:%d", mqtt.host, mqtt.port)
        return "already running"
    if mqtt.host not in ("127.0.0.1", "localhost", "::1"):
        log.warning("no MQTT broker answers on %s:%d; the gateway keeps retrying", mqtt.host, mqtt.port)
        return "not reachable; retrying"
    await stack.enter_async_context(EmbeddedBroker(mqtt.host, mqtt.port))
    log.warning("no MQTT broker on %s:%d: started an embedded one (amqtt) for the demo", mqtt.host, mqtt.port)
    return "embedded amqtt, started by the demo"


async def _run_demo(
    gw: Gateway,
    config: Config,
    args: argparse.Namespace,
    switch: SimulatorSwitch | None,
    toggle: asyncio.Event,
    broker: str,
    dnc: Any = None,
) -> None:
    mapping = config.machines[0]
    machine = gw.tree.machines[mapping.machine]
    jobs = gw.jobs
    busy = (lambda: jobs.machine_busy(machine.name)) if jobs is not None else (lambda: False)
    tasks: list[tuple[str, Callable[[], Coroutine[object, object, None]]]] = [
        ("demo:driver", lambda: keep_program_running(machine, busy))
    ]
    if jobs is not None and args.sim_dnc_port is not None and len(config.machines) > 1:
        serial = gw.tree.machines[config.machines[1].machine]
        state = serial.nodes["Machine/State"]
        tasks.append(("demo:drip", lambda: keep_dripping(jobs, serial.name, lambda: state.sample.value == 0)))
        if dnc is not None:
            tasks.append(("demo:punch", lambda: punch_once(dnc, config.state_dir, serial.name)))
    if switch is None:
        log.info("a simulator is already listening on port %d: using it", args.sim_opcua_port)
    else:
        tasks.append(("demo:simulator", switch.run))
        _install_toggle(toggle)
    print_banner(gw, mapping, args, switch is None, broker, config.machines[1:])
    await gw.run(*tasks)


class SimulatorSwitch:
    """The in-process simulator: started before the gateway; each toggle stops it or starts it again."""

    def __init__(self, config: Config, args: argparse.Namespace, toggle: asyncio.Event) -> None:
        self.args = args
        self.toggle = toggle
        self.store = config.state_dir / "simulator-store"
        self._sim: Any = None

    async def __aenter__(self) -> SimulatorSwitch:
        await self._start()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self._stop()

    async def _start(self) -> None:
        from simulator.runner import Simulator

        args = self.args
        self.store.mkdir(parents=True, exist_ok=True)
        sim = Simulator(
            opcua_port=args.sim_opcua_port,
            ftp_port=args.sim_ftp_port,
            speed=args.speed,
            store=self.store,
            shdr_port=args.sim_shdr_port,
            focas_port=args.sim_focas_port,
            **demo_plc.simulator_ports(args),
        )
        await sim.__aenter__()
        self._sim = sim
        log.info("simulator running (OPC UA %d, FTP %d)", args.sim_opcua_port, args.sim_ftp_port)

    async def _stop(self) -> None:
        sim, self._sim = self._sim, None
        if sim is not None:
            await sim.__aexit__(None, None, None)

    async def run(self) -> None:
        while True:
            await self.toggle.wait()
            self.toggle.clear()
            if self._sim is not None:
                await self._stop()
                log.warning(
                    "simulator STOPPED: values go Bad within seconds. "
                    "Press Enter (or kill -USR1) to start it again."
                )
            else:
                await self._start()


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


def print_banner(
    gw: Gateway,
    mapping: MachineMapping,
    args: argparse.Namespace,
    external: bool,
    broker: str = "off",
    serial: tuple[MachineMapping, ...] = (),
) -> None:
    opcua = gw.sink("opcua")
    endpoint = getattr(opcua, "endpoint", f"opc.tcp://127.0.0.1:{args.opcua_port}/cnc-gateway")
    lines = [
        "",
        "cnc-gateway demo",
        (
            f"  OPC UA server    {endpoint.replace('0.0.0.0', '127.0.0.1')}  "
            "(None, Basic256Sha256, Aes128/Aes256 endpoints; trust a client by moving its certificate from "
            f"{args.state_dir}/pki/rejected/ to trusted/)"
        ),
        "  users            viewer, operator, engineer, admin (OPC UA and the web console); "
        + (
            f"password from {DEMO_PASSWORD_ENV}"
            if os.environ.get(DEMO_PASSWORD_ENV)
            else f"password: the user name ({DEMO_PASSWORD_ENV} changes it)"
        )
        + "; anonymous clients are viewers",
        (
            f"  browse           Objects/Machines/{mapping.machine}/Axes/X/Position, "
            "Feed/Override (operators write), Status/..."
        ),
        f"  node ids         ns=2;s={mapping.machine}/Axes/X/Position",
        *umati_banner(mapping),
        (
            f"  simulator        {mapping.driver.endpoint} (OPC UA), "
            f"ftp://127.0.0.1:{args.sim_ftp_port}/DATA/Programs "
        )
        + ("(already running)" if external else "(in-process)"),
    ]
    mqtt = config_mqtt(gw)
    if mqtt is not None:
        lines += [
            f"  MQTT broker      mqtt://{mqtt.host}:{mqtt.port} ({broker})",
            f"  watch            mosquitto_sub -v -t '{mqtt.prefix}/#'",
            f"  write            mosquitto_pub -t {mqtt.prefix}/{mapping.machine}/feed/override/set -m 50",
        ]
    lines += sparkplug_banner(gw, mapping)
    if gw.jobs is not None and gw.jobs.inbox is not None:
        inbox = gw.jobs.inbox
        password = os.environ.get(DEMO_INBOX_PASSWORD_ENV) or DEMO_INBOX_PASSWORD
        where = f"{DEMO_INBOX_USER}:{password}@{inbox.url.split('://', 1)[1]}{mapping.machine}/"
        lines += [
            (
                f"  FTP job inbox    {inbox.url}  user {DEMO_INBOX_USER}, password {password!r} "
                f"(set {DEMO_INBOX_PASSWORD_ENV} to change it)"
            ),
            f"  send a job       curl -T part.nc ftp://{where}",
            (
                f"  jobs             cnc-gateway jobs list; OPC UA Objects/Machines/{mapping.machine}/Jobs; "
                "the program starts when the machine is idle"
            ),
        ]
    lines += dnc_banner(serial, mqtt)
    lines += web_banner(gw)
    lines += copydata_banner(mapping, str(args.mapping or "mappings/laser-sim.yaml"))
    lines += mtconnect_banner(gw, args, external)
    lines += demo_plc.banner(args, None if mqtt is None else mqtt.prefix)
    if not external:
        lines.append(
            "  outage drill     press Enter (or kill -USR1 <pid>) to stop the simulator, again to restart it"
        )
    lines += ["  stop             Ctrl-C", ""]
    print("\n".join(lines), flush=True)


def umati_banner(mapping: MachineMapping) -> list[str]:
    """The umati view's line, when the mapping has a `umati:` section (docs/umati.md)."""
    view = getattr(mapping, "umati", None)
    if view is None:
        return []
    parts = [c.name for c in view.channels] + ([f"{view.laser.name} (LaserMonitoring)"] if view.laser else [])
    return [
        (
            f"  umati            Objects/Machines/{mapping.machine}: an OPC 40501 MachineTool (Machinery ns, "
            f"ns=2;s=umati:{mapping.machine}): Identification, Monitoring/{', '.join(parts)}, "
            "Production/ActiveProgram, Notification/Messages (docs/umati.md)"
        )
    ]


def dnc_banner(serial: tuple[MachineMapping, ...], mqtt: MqttConfig | None) -> list[str]:
    """The serial machine: where its line is, and where to watch its drip-feed."""
    lines = []
    for m in serial:
        if m.jobs is None or not isinstance(m.jobs.controller, ControllerSerial):
            continue
        c = m.jobs.controller
        line = f"{c.baud} baud {c.bytesize}{c.parity[0].upper()}{c.stopbits}, {c.handshake}, {c.mode}"
        jobs = f"OPC UA Objects/Machines/{m.machine}/Jobs/Block, LeadSeconds, RemainingSeconds"
        lines += [
            f"  serial machine   {m.machine}: {c.where} ({line}); drip-feeds {DRIP_NAME} every so often",
            f"  drip progress    cnc-gateway jobs list; {jobs}",
        ]
        if mqtt is not None:
            lines.append(
                f"  drip control     mosquitto_pub -t {mqtt.prefix}/{m.machine}/commands/DripPause -m '{{}}' "
                '(DripResume, DripAbort; DripRestart {"Job": …, "Line": …})'
            )
    return lines


def sparkplug_banner(gw: Gateway, mapping: MachineMapping) -> list[str]:
    """The edge node's ids and topics, and how to watch them or point a Sparkplug host at them."""
    sparkplug = gw.config.gateway.sparkplug
    if sparkplug is None:
        return []
    group, edge, machine = sparkplug.group_id, sparkplug.edge_node_id, mapping.machine
    host = sparkplug.primary_host_id
    broker = sparkplug.connection(gw.config.gateway.mqtt)
    waits = f"; births wait for primary host {host}'s STATE" if host else ""
    node = f"spBv1.0/{group}/{{NBIRTH,NDATA,NDEATH,NCMD}}/{edge}"
    device = f"spBv1.0/{group}/{{DBIRTH,DDATA,DDEATH,DCMD}}/{edge}/{machine}"
    watch = f"cnc-gateway sparkplug watch --host {broker.host} --port {broker.port} --group {group}"
    return [
        f"  Sparkplug B      group {group}, edge node {edge}, device {machine} (same broker){waits}",
        f"  topics           {node}, {device}",
        f"  Sparkplug host   {watch}  (or Ignition's MQTT Engine: README, Sparkplug B)",
    ]


def mtconnect_banner(gw: Gateway, args: argparse.Namespace, external: bool) -> list[str]:
    """Where the MTConnect agent answers, and the simulator's adapter for an MTConnect-in gateway."""
    lines = []
    try:
        agent = gw.sink("mtconnect")
    except KeyError:
        agent = None
    if agent is not None:
        url = getattr(agent, "url", f"http://127.0.0.1:{args.mtconnect_port}")
        lines.append(f"  MTConnect agent  {url}/probe  (curl {url}/current; /sample?interval=1000; JSON)")
    if not external and args.sim_shdr_port is not None:
        lines.append(
            f"  SHDR adapter     shdr://127.0.0.1:{args.sim_shdr_port}  (the simulator's; "
            "mappings/laser-sim-shdr.yaml reads it: README, MTConnect)"
        )
    return lines + demo_focas.banner(args.sim_focas_port, external)


def web_banner(gw: Gateway) -> list[str]:
    """Where the web console, the REST API and /metrics are."""
    try:
        web = gw.sink("web")
    except KeyError:
        return []
    url = str(getattr(web, "url", ""))
    return [
        f"  web console      {url}  (log in as a user above; anonymous visitors look as viewers)",
        (
            f"  REST API         {url}api/openapi.json; token: cnc-gateway tokens create --user operator "
            f"--state-dir {gw.config.state_dir}"
        ),
        f"  metrics          {url}metrics  (Prometheus), {url}readyz",
    ]


def copydata_banner(mapping: MachineMapping, mapping_file: str) -> list[str]:
    """How to watch the frames a nesting package would get."""
    if mapping.copydata is None:
        return []
    lines = []
    for target in mapping.copydata.targets:
        if target.transport == "tcp-server":
            host = "127.0.0.1" if target.listen_address in ("0.0.0.0", "::") else target.listen_address
            lines.append(
                f"  COPYDATA frames  cnc-gateway frames listen --tcp {host}:{target.listen_port} "
                f"--mapping {mapping_file}"
            )
        else:
            lines.append(f"  COPYDATA frames  {target.name}: {target.describe()}")
    return lines


def config_mqtt(gw: Gateway) -> MqttConfig | None:
    return gw.config.gateway.mqtt

"""`cnc-simulator`: run the simulated laser cutter until SIGINT/SIGTERM."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import math
import os
import signal
import sys
from collections.abc import Sequence
from pathlib import Path

from simulator.dnc import DncOptions
from simulator.dnc.options import _port_or_off, add_dnc_arguments, dnc_banner, dnc_options
from simulator.errors import SimulatorError
from simulator.fleet import SimulatorFleet
from simulator.focas import DEFAULT_PORT as FOCAS_PORT
from simulator.focas import DEFAULT_SESSIONS as FOCAS_SESSIONS
from simulator.haas_mdc import DEFAULT_PORT as HAAS_PORT
from simulator.modbus import DEFAULT_PORT as MODBUS_PORT
from simulator.noise import NoiseSpec, noise_mapping
from simulator.runner import Simulator
from simulator.s7_face import DEFAULT_PORT as S7_PORT
from simulator.shdr import DEFAULT_PORT as SHDR_PORT
from simulator.variables import NAMESPACE_URI

log = logging.getLogger("simulator")

SHDR_ENV = "CNC_SIM_SHDR_PORT"
FOCAS_ENV = "CNC_SIM_FOCAS_PORT"
HAAS_ENV = "CNC_SIM_HAAS_PORT"
MODBUS_ENV = "CNC_SIM_MODBUS_PORT"
S7_ENV = "CNC_SIM_S7_PORT"

NOISY = ("asyncua", "aioftp", "snap7")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="cnc-simulator",
        description="A simulated laser cutter that runs G-code, with OPC UA and an FTP program store.",
    )
    p.add_argument(
        "--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1; 0.0.0.0 for all)"
    )
    p.add_argument("--opcua-port", type=int, default=4841, help="OPC UA port (default 4841)")
    p.add_argument("--ftp-port", type=int, default=2122, help="FTP port (default 2122)")
    p.add_argument(
        "--speed", type=_positive, default=1.0, help="simulated seconds per real second (default 1)"
    )
    p.add_argument(
        "--tick", type=_positive, default=0.02, help="seconds between updates (default 0.02, 50 Hz)"
    )
    p.add_argument(
        "--store", type=Path, default=None, help="program store folder (default: a fresh temporary one)"
    )
    p.add_argument(
        "--loop", metavar="NAME", default=None, help="select and start NAME, and restart it after each end"
    )
    p.add_argument("--ftp-user", default=None, help="FTP user (default $CNC_SIM_FTP_USER or 'cnc')")
    p.add_argument(
        "--ftp-password", default=None, help="FTP password (default $CNC_SIM_FTP_PASSWORD or 'simulator')"
    )
    fleet = p.add_argument_group("fleet mode (a plant's load for gateway shards)")
    fleet.add_argument(
        "--machines", type=int, default=1, metavar="N",
        help="serve N laser cutters (laser-001 …): one OPC UA server on the base port, a folder per machine,"
        " and an FTP server each on the base FTP port + i (0: free ports); only OPC UA and FTP"
        " (default 1: the one machine with every face)",
    )  # fmt: skip
    fleet.add_argument(
        "--fleet-mappings", type=Path, default=None, metavar="DIR",
        help="with --machines: write a gateway mapping file per machine into DIR at start",
    )  # fmt: skip
    p.add_argument(
        "--fleet-address", default=None, metavar="HOST",
        help="with --fleet-mappings: the host the gateway reaches the simulator at, in the mapping files"
        " (default: the --host it listens on; a compose service's name when that is 0.0.0.0)",
    )  # fmt: skip
    p.add_argument("--opcua-user", default=None, help="require this OPC UA user (default: anonymous access)")
    p.add_argument("--opcua-password", default=None, help="password of --opcua-user")
    noise = p.add_argument_group("noise mode (benchmark load)")
    noise.add_argument(
        "--noise-variables", type=int, default=0, metavar="N",
        help="add N Double variables under Objects/PLC/Tasks/Noise that change at --noise-rate",
    )  # fmt: skip
    noise.add_argument(
        "--noise-rate", type=_rate, default=1000.0, metavar="R",
        help="total changes per second across the noise variables (default 1000; 'max': as fast as possible)",
    )  # fmt: skip
    noise.add_argument(
        "--noise-per-folder",
        type=int,
        default=200,
        metavar="K",
        help="noise variables per folder (default 200)",
    )
    noise.add_argument(
        "--noise-mapping", type=Path, default=None, metavar="FILE",
        help="write a gateway mapping file for the noise variables to FILE at start",
    )  # fmt: skip
    add_dnc_arguments(p)
    p.add_argument(
        "--shdr-port", type=_port_or_off, default=_shdr_default(), metavar="PORT",
        help=f"MTConnect adapter (SHDR) port (default ${SHDR_ENV} or {SHDR_PORT}; 'off')",
    )  # fmt: skip
    p.add_argument(
        "--focas-port", type=_port_or_off, default=_port_default(FOCAS_ENV, FOCAS_PORT), metavar="PORT",
        help=f"Fanuc FOCAS2 Ethernet port (default ${FOCAS_ENV} or {FOCAS_PORT}; 'off')",
    )  # fmt: skip
    p.add_argument(
        "--focas-sessions", type=int, default=FOCAS_SESSIONS, metavar="N",
        help=f"FOCAS sessions open at once before one is refused, as a Fanuc's (default {FOCAS_SESSIONS})",
    )  # fmt: skip
    p.add_argument(
        "--haas-port", type=_port_or_off, default=_port_default(HAAS_ENV, HAAS_PORT), metavar="PORT",
        help=f"Haas NGC machine data collection port (default ${HAAS_ENV} or {HAAS_PORT}; 'off')",
    )  # fmt: skip
    p.add_argument(
        "--modbus-port", type=_port_or_off, default=_port_default(MODBUS_ENV, MODBUS_PORT), metavar="PORT",
        help=f"the chiller's Modbus TCP port (default ${MODBUS_ENV} or {MODBUS_PORT}; 'off')",
    )  # fmt: skip
    p.add_argument(
        "--s7-port", type=_port_or_off, default=_port_default(S7_ENV, S7_PORT), metavar="PORT",
        help=f"the PLC's S7 (ISO-on-TCP) port (default ${S7_ENV} or {S7_PORT}; 'off')",
    )  # fmt: skip
    p.add_argument("--log-level", choices=["debug", "info", "warning", "error"], default="info")
    return p


def _shdr_default() -> int | None:
    return _port_default(SHDR_ENV, SHDR_PORT)


def _port_default(env: str, default: int) -> int | None:
    text = os.environ.get(env)
    if text is None:
        return default
    try:
        return _port_or_off(text)
    except argparse.ArgumentTypeError:
        return default


def _rate(text: str) -> float:
    if text.strip().lower() in ("max", "inf"):
        return math.inf
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number (or 'max')") from None
    if not value >= 0:
        raise argparse.ArgumentTypeError("must be >= 0")
    return value


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not value > 0:
        raise argparse.ArgumentTypeError("must be > 0")
    return value


def configure_logging(level: str) -> None:
    logging.basicConfig(
        level=getattr(logging, level.upper()),
        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s",
        datefmt="%Y-%m-%d %H:%M:%S",
        stream=sys.stderr,
        force=True,
    )
    for name in NOISY:
        logging.getLogger(name).setLevel(logging.DEBUG if level == "debug" else logging.WARNING)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if (args.opcua_user is None) != (args.opcua_password is None):
        build_parser().error("--opcua-user and --opcua-password go together")
    if args.noise_variables < 0 or args.noise_per_folder < 1:
        build_parser().error("--noise-variables must be >= 0 and --noise-per-folder >= 1")
    if args.noise_mapping is not None and not args.noise_variables:
        build_parser().error("--noise-mapping needs --noise-variables")
    if args.machines < 1:
        build_parser().error("--machines must be >= 1")
    if args.fleet_mappings is not None and args.machines < 2:
        build_parser().error("--fleet-mappings needs --machines N (N >= 2)")
    if args.machines > 1 and (args.noise_variables or args.opcua_user):
        build_parser().error("--machines serves plain laser cutters: no --noise-variables or --opcua-user")
    try:
        dnc = dnc_options(args)
    except ValueError as exc:
        build_parser().error(str(exc))
    configure_logging(args.log_level)
    try:
        if args.machines > 1:
            return asyncio.run(serve_fleet(args))
        return asyncio.run(serve(args, dnc))
    except KeyboardInterrupt:  # a signal before the handlers were installed
        return 0


async def serve(args: argparse.Namespace, dnc: DncOptions | None = None) -> int:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):  # Windows has no signal handlers
            loop.add_signal_handler(sig, stop.set)
    simulator = Simulator(
        host=args.host,
        opcua_port=args.opcua_port,
        ftp_port=args.ftp_port,
        speed=args.speed,
        tick=args.tick,
        store=args.store,
        loop_program=args.loop,
        ftp_user=args.ftp_user,
        ftp_password=args.ftp_password,
        opcua_user=args.opcua_user,
        opcua_password=args.opcua_password,
        noise=_noise(args),
        dnc=dnc,
        shdr_port=args.shdr_port,
        focas_port=args.focas_port,
        focas_sessions=args.focas_sessions,
        haas_port=args.haas_port,
        modbus_port=args.modbus_port,
        s7_port=args.s7_port,
    )
    try:
        async with simulator:
            if simulator.noise is not None and args.noise_mapping is not None:
                text = noise_mapping(simulator.noise.spec, simulator.opcua_endpoint)
                try:
                    args.noise_mapping.write_text(text, encoding="utf-8")
                except OSError as exc:
                    log.error("cannot write %s: %s", args.noise_mapping, exc.strerror or exc)
                    return 1
            print_banner(simulator, args)
            await stop.wait()
            log.info("shutting down")
    except SimulatorError as exc:
        log.error("cannot start: %s", exc)
        return 1
    return 0


async def serve_fleet(args: argparse.Namespace) -> int:
    """`--machines N`: N laser cutters, one OPC UA server and an FTP server each, until SIGINT/SIGTERM."""
    stop = _stop_on_signals()
    fleet = SimulatorFleet(
        args.machines,
        host=args.host,
        opcua_port=args.opcua_port,
        ftp_port=args.ftp_port,
        speed=args.speed,
        tick=args.tick,
        loop_program=args.loop,
        store_root=args.store,
        ftp_user=args.ftp_user,
        ftp_password=args.ftp_password,
    )
    try:
        async with fleet:
            if args.fleet_mappings is not None:
                try:
                    fleet.write_mappings(args.fleet_mappings, args.fleet_address)
                except OSError as exc:
                    log.error(
                        "cannot write the mappings into %s: %s", args.fleet_mappings, exc.strerror or exc
                    )
                    return 1
            lines = [f"cnc-simulator: a fleet of {fleet.count} laser cutters, OPC UA {fleet.opcua.endpoint}"]
            for name, sim in fleet.names():
                lines.append(
                    f"  {name}  {sim.opcua_endpoint} ({name}/)  ftp://{sim.host}:{sim.ftp_port}/DATA/Programs"
                )
            if args.fleet_mappings is not None:
                lines.append(f"  mappings written to {args.fleet_mappings}")
            lines.append("  stop     Ctrl-C")
            print("\n".join(["", *lines, ""]), flush=True)
            await stop.wait()
            log.info("shutting down")
    except SimulatorError as exc:
        log.error("cannot start: %s", exc)
        return 1
    return 0


def _stop_on_signals() -> asyncio.Event:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):  # Windows has no signal handlers
            loop.add_signal_handler(sig, stop.set)
    return stop


def _noise(args: argparse.Namespace) -> NoiseSpec | None:
    if not args.noise_variables:
        return None
    return NoiseSpec(args.noise_variables, args.noise_rate, args.noise_per_folder)


def print_banner(sim: Simulator, args: argparse.Namespace) -> None:
    programs = ", ".join(sim.programs.names()) or "(none)"
    auth = f"user {args.opcua_user}" if args.opcua_user else "anonymous"
    lines = [
        "",
        "cnc-simulator: laser cutter, X 0..3000 Y 0..1500 Z -5..100 mm",
        f"  OPC UA   {sim.opcua_endpoint}  (security None, {auth}; {NAMESPACE_URI} is ns=2)",
        "           e.g. ns=2;s=::AsGlobalPV:gAxis[0].ActPos, write ns=2;s=::AsGlobalPV:gCmd.Start",
        f"  FTP      ftp://{sim.host}:{sim.ftp_port}/DATA/Programs  (user {sim.ftp_user})",
        f"  store    {sim.store}",
        f"  programs {programs}",
        f"  speed    {sim.speed:g}x" + (f", looping {sim.loop_program}" if sim.loop_program else ""),
        *(_noise_banner(sim, args) if sim.noise is not None else []),
        *(dnc_banner(sim.dnc) if sim.dnc is not None else []),
        *(
            [f"  MTConnect {sim.shdr.url}  (SHDR adapter: mappings/laser-sim-shdr.yaml reads it)"]
            if sim.shdr
            else []
        ),
        *(
            [
                (
                    f"  FOCAS    {sim.focas.url}  (Fanuc FOCAS2, {sim.focas.max_sessions} sessions: "
                    "mappings/fanuc-sim.yaml reads it)"
                )
            ]
            if sim.focas
            else []
        ),
        *([f"  Haas MDC {sim.haas.url}  (Q-commands; mappings/haas-sim.yaml reads it)"] if sim.haas else []),
        *(
            [f"  Modbus   {sim.modbus.url}  (the chiller, unit 1: mappings/chiller-sim.yaml)"]
            if sim.modbus
            else []
        ),
        "  stop     Ctrl-C",
        "",
    ]
    print("\n".join(lines), flush=True)


def _noise_banner(sim: Simulator, args: argparse.Namespace) -> list[str]:
    assert sim.noise is not None
    spec = sim.noise.spec
    rate = "as fast as possible" if math.isinf(spec.rate) else f"{spec.rate:g} changes/s"
    lines = [
        f"  noise    {spec.variables} Doubles under Objects/PLC/Tasks/Noise, {rate} (value = sequence number)"
    ]
    if args.noise_mapping is not None:
        lines.append(f"           gateway mapping written to {args.noise_mapping}")
    return lines


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

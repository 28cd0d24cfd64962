"""The simulator with noise variables, in its own process: `rate` sets the load, `snap` reports it."""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import math
from pathlib import Path
from typing import Any

from bench.agents.protocol import serve, setup_logging
from gateway.diagnostics import GC_PAUSES
from simulator.noise import NoiseSpec
from simulator.runner import Simulator


def _rate(request: dict[str, Any]) -> float:
    rate = request["rate"]
    return math.inf if rate in ("max", None) else float(rate)


async def main(args: argparse.Namespace) -> None:
    GC_PAUSES.install()  # the collector's pauses: a stall here ages every value the gateway receives
    spec = NoiseSpec(args.variables, 0.0, args.per_folder)
    async with Simulator(
        opcua_port=args.opcua_port, ftp_port=0, store=args.store, noise=spec, ftp_password="simulator"
    ) as sim:
        noise = sim.noise
        assert noise is not None

        def rate(request: dict[str, Any]) -> dict[str, Any]:
            noise.set_rate(_rate(request))
            return {}

        def snap(request: dict[str, Any]) -> dict[str, Any]:
            return {**dataclasses.asdict(noise.stats()), "gc": GC_PAUSES.stats()}

        await serve(
            {"rate": rate, "snap": snap},
            {"endpoint": sim.opcua_endpoint, "ftp_port": sim.ftp_port, "store": str(sim.store)},
        )


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("--variables", type=int, required=True)
    parser.add_argument("--per-folder", type=int, default=200)
    parser.add_argument("--opcua-port", type=int, default=0)
    parser.add_argument("--store", type=Path, default=None)
    setup_logging()
    asyncio.run(main(parser.parse_args()))

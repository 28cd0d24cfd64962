"""The real gateway (gateway.app.Gateway) in its own process, with its diagnostics on request.

`--inject` replaces the sources by the in-process injector (bench/agents/injector.py),
so that the sinks are measured alone; `rate` then sets its load. `--inject-bound N` holds the
injector back while the MQTT sink has N or more changes on its hands (waiting in its hub
subscription, in its backlog, or in flight): flat out, it then measures the sink's capacity with
every change kept (bench/scenarios/qos1.py).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import dataclasses
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bench.agents.ages import Ages
from bench.agents.injector import Injector
from bench.agents.protocol import serve, setup_logging
from gateway.app import Gateway
from gateway.config.loader import load
from gateway.diagnostics import GC_PAUSES, snapshot
from gateway.shims.loop import ENV, LOOPS, loop_factory, run


async def main(args: argparse.Namespace) -> None:
    GC_PAUSES.install()  # the collector's pauses, per step (bench/scenarios/mirror.py)
    ages = Ages() if args.ages else None
    if ages is not None:
        ages.install()
    config = load([args.config])
    gateway = Gateway(config)
    injector: Injector | None = None
    if args.inject:
        gateway.sources = []
        nodes = [n for m in gateway.tree.machines.values() for n in m.mapped]
        injector = Injector(
            nodes, hold=_mqtt_holds(gateway, args.inject_bound) if args.inject_bound else None
        )
        for machine in gateway.tree.machines.values():  # the injector is their controller, and it is there
            machine.status.connected()
    tasks: list[asyncio.Task[None]] = []
    async with gateway:
        tasks.append(asyncio.create_task(gateway.run(), name="bench:gateway"))
        if injector is not None:
            tasks.append(asyncio.create_task(injector.run(), name="bench:injector"))

        def snap(request: dict[str, Any]) -> dict[str, Any]:
            out = snapshot(gateway)
            out["running"] = not tasks[0].done()
            if injector is not None:
                out["injector"] = dataclasses.asdict(injector.stats())
            return out

        def rate(request: dict[str, Any]) -> dict[str, Any]:
            if injector is None:
                raise RuntimeError("rate needs --inject")
            value = request["rate"]
            injector.set_rate(math.inf if value in ("max", None) else float(value))
            return {}

        def take_ages(request: dict[str, Any]) -> dict[str, Any]:
            if ages is None:
                raise RuntimeError("ages needs --ages")
            return ages.take()

        try:
            await serve(
                {"snap": snap, "rate": rate, "ages": take_ages}, {"opcua": config.gateway.opcua.endpoint}
            )
        finally:
            for task in tasks:
                task.cancel()
            for task in tasks:
                with contextlib.suppress(BaseException):
                    await task


def _mqtt_holds(gateway: Gateway, bound: int) -> Callable[[], bool]:
    """True while the MQTT sink has `bound` or more changes on its hands (its public figures)."""
    sink = next(s for s in gateway.sinks if s.name == "mqtt")

    def holds() -> bool:
        waiting = sum(s.backlog for s in gateway.tree.hub.subscriptions if s.name == "mqtt")
        health = sink.health()
        return waiting + (health.backlog or 0) + (health.in_flight or 0) >= bound

    return holds


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("--config", type=Path, required=True)
    parser.add_argument("--inject", action="store_true")
    parser.add_argument("--inject-bound", type=int, default=0, help="hold the injector back at N pending")
    parser.add_argument("--ages", action="store_true", help="record the age of changes at ingest and write")
    parser.add_argument("--loop", choices=LOOPS, default=None, help=f"default: ${ENV}, else asyncio")
    setup_logging()
    arguments = parser.parse_args()
    run(main(arguments), loop_factory(arguments.loop))

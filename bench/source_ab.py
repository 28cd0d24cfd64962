"""The OPC UA source alone, A/B: CPU per 1,000 changes with asyncua's decoding and with the compiled reader.

`python -m bench.source_ab [--variables N] [--rate R] [--window S] [--rounds K]` starts the simulator's
noise mode in a process of its own, runs the gateway's real OPC UA source (gateway.sources.opcua.client)
into a variable tree with no sink in this process, and alternates windows with the compiled PublishResponse
reader forced off and on (`publish_decode.PURE`), measuring this process's CPU time per change taken.
Alternating windows in one process cancels most of a shared machine's drift; the medians are printed as
JSON (ms of CPU per 1,000 changes). bench/scenarios/baselines.py runs it as `source_decode`.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import yaml

from bench.procs import Agent
from gateway.config.mapping import MachineMapping
from gateway.model.tree import VariableTree
from gateway.sources.opcua import publish_decode
from gateway.sources.opcua.client import OpcUaSource
from simulator.noise import NoiseSpec, noise_mapping


async def measure(
    variables: int, rate: float, window: float, rounds: int, modes: tuple[str, ...] = ("asyncua", "compiled")
) -> dict[str, Any]:
    workdir = Path(tempfile.mkdtemp(prefix="cnc-source-ab-"))
    sim = await Agent.start(
        "source-ab-sim", "bench.agents.simulator", ["--variables", str(variables)], workdir
    )
    try:
        text = noise_mapping(NoiseSpec(variables), sim.ready["endpoint"])
        mapping = MachineMapping.model_validate(yaml.safe_load(text))
        machine = VariableTree([mapping.definition()]).machines[mapping.machine]
        source = OpcUaSource(machine, mapping)
        taken = 0
        process = source._process

        def counting(changes: list[Any], statuses: list[int], lost: Any) -> None:
            nonlocal taken
            taken += len(changes)
            process(changes, statuses, lost)

        source._process = counting  # type: ignore[method-assign]
        per_1000: dict[str, list[float]] = {mode: [] for mode in modes}
        async with source:
            task = asyncio.create_task(source.run(), name="source-ab")
            try:
                deadline = time.monotonic() + 60
                while not machine.status.is_connected:
                    if time.monotonic() > deadline:
                        raise TimeoutError("the source did not connect to the simulator")
                    await asyncio.sleep(0.1)
                await sim.ask("rate", rate=rate)
                await asyncio.sleep(2.0)
                for _ in range(rounds):
                    for mode in per_1000:
                        publish_decode.PURE = mode == "asyncua"
                        await asyncio.sleep(0.5)
                        n0, cpu0 = taken, time.process_time()
                        await asyncio.sleep(window)
                        cpu, n = time.process_time() - cpu0, taken - n0
                        per_1000[mode].append(1e6 * cpu / n if n else float("nan"))
                await sim.ask("rate", rate=0)
            finally:
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)
        return {
            "variables": variables,
            "rate": rate,
            "windows": per_1000,
            **{mode: statistics.median(values) for mode, values in per_1000.items()},
        }
    finally:
        await sim.stop()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--variables", type=int, default=1000)
    parser.add_argument("--rate", type=float, default=5000.0)
    parser.add_argument("--window", type=float, default=4.0)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument(
        "--modes", nargs="+", choices=["asyncua", "compiled"], default=["asyncua", "compiled"],
        help="decoders to alternate (one alone: to profile it, e.g. under py-spy)",
    )  # fmt: skip
    args = parser.parse_args()
    found = asyncio.run(measure(args.variables, args.rate, args.window, args.rounds, tuple(args.modes)))
    print(json.dumps(found))


if __name__ == "__main__":
    main()
